#!/usr/bin/env bash
# Last step of the demo models' recipe, after
#   bash scripts/train/train_demo.sh           # the teacher -> stablemo/assets/demo_bundle
#   bash scripts/train/distill_demo.sh lcm     # its 1-step LCM student -> runs/distill_lcm_synth, bundles/demo_lcm
#   bash scripts/train/train_controlnet.sh      # its pelvis ControlNet on the shipped student (optional)
# this exports the student into the package (stablemo/assets/demo_student, the page's default model),
# the ControlNet when its run is there (stablemo/assets/demo_controlnet; run this script once before
# training it, so that it trains on the student shipped here, and once after), and gives the bundles
# what generation reads beside the network: the length predictor (a motion
# asked for without a length takes its text's, scripts/text/length_predictor.py) and their training
# captions (a prompt unlike all of them gets a warning, scripts/text/familiarity.py). Both are
# trained from the data and the frozen text encoder alone, so every shipped bundle shares them (the
# ControlNet's too, which carries its own base).
set -euo pipefail
cd "$(dirname "$0")/../.."
STABLEMO=${STABLEMO:-.venv/bin/stablemo}
PYTHON=${PYTHON:-.venv/bin/python}
student=runs/distill_lcm_synth/checkpoints/last.ckpt
[ -f "$student" ] || { echo "ship_demo.sh: $student is missing: run scripts/train/distill_demo.sh lcm first" >&2; exit 2; }
"$STABLEMO" export "$student" --out stablemo/assets/demo_student --overwrite
controlnet=runs/controlnet_lcm_pelvis_toward_clip/checkpoints/last.ckpt  # train_controlnet.sh's last stage
if [ -f "$controlnet" ]; then
    "$STABLEMO" export "$controlnet" --out stablemo/assets/demo_controlnet --overwrite
else
    echo "ship_demo.sh: no $controlnet: stablemo/assets/demo_controlnet is left as it is" >&2
fi
# The length predictor learns an action's own length from clips with tight rest: in the varied data a
# clip's idle rest is drawn at random, which no text predicts (it measured 32 % of test lengths within
# one bin there against 48 % on tight clips). The models fill any longer length with rest themselves.
# Its captions, and the familiar ones, are those of the wider vocabulary the teacher last trained on
# (--captions varied: every plain caption can be written in it; docs/training.md, "Other captions").
[ -f data/synth_tight_varied/Mean.npy ] || "$STABLEMO" data synth --out data/synth_tight_varied --num 2000 --seed 0 \
    --rest tight --captions varied
"$PYTHON" scripts/text/length_predictor.py --data data/synth_tight_varied stablemo/assets/demo_bundle \
    stablemo/assets/demo_student stablemo/assets/demo_controlnet
"$PYTHON" scripts/text/familiarity.py --data data/synth_tight_varied --threshold 0.65 stablemo/assets/demo_bundle \
    stablemo/assets/demo_student stablemo/assets/demo_controlnet
