#!/usr/bin/env bash
# Recipe of the shipped ControlNet (stablemo/assets/demo_controlnet): a root-only pelvis ControlNet on the
# shipped 1-step student (stablemo/assets/demo_student), whose steps on the floor point at the next
# target, trained in two stages on the path-walk data (docs/control.md, "Motion ControlNet"):
#   1. configs/control/controlnet_lcm_pelvis_floor.yaml + controlnet_lcm_pelvis_toward.yaml: 1500 steps
#      against the student's own motion                                      -> bundles/demo_controlnet_toward
#   2. + configs/control/pelvis_toward_clip.yaml: 1500 steps from stage 1 against the clips' own paths
#                                                                            -> bundles/demo_controlnet_toward_clip
# Then scripts/train/ship_demo.sh exports stage 2's run into the package with the text models.
# Resumable like train_demo.sh: a stage whose bundle holds its step count, trained on the student that is
# shipped now (by the SHA-256 of its weights that the bundle records), is skipped; an unfinished one
# continues from its last.ckpt. A run folder started on another student resumes that student's weights:
# move it away first. On the 2-core CPU: about 30 + 20 min (2026-12-07), plus the data.
#   bash scripts/train/train_controlnet.sh                # both stages
#   bash scripts/train/train_controlnet.sh --stage 2      # one stage (it needs the stage before it)
set -euo pipefail
cd "$(dirname "$0")/../.."
STABLEMO=${STABLEMO:-.venv/bin/stablemo}
PYTHON=${PYTHON:-.venv/bin/python}
STUDENT=stablemo/assets/demo_student
source scripts/train/stages.sh
only=
case "${1:-}" in
  "") ;;
  --stage) only=${2:-}; [[ $only =~ ^[12]$ ]] || { echo "train_controlnet.sh: --stage takes 1 or 2, got '${2:-}'" >&2; exit 2; } ;;
  *) echo "train_controlnet.sh: unknown argument '$1' (usage: train_controlnet.sh [--stage 1|2])" >&2; exit 2 ;;
esac
[ -f "$STUDENT/model.safetensors" ] || { echo "train_controlnet.sh: $STUDENT is missing: bash scripts/train/ship_demo.sh" >&2; exit 2; }

done_on_student() {  # BUNDLE STEPS: does BUNDLE hold a ControlNet trained STEPS steps on today's student?
  [ -f "$1/config.json" ] && "$PYTHON" -c 'import json, sys
from stablemo.inference.bundle import weights_sha256
training = json.load(open(sys.argv[1] + "/config.json"))["training"]
sys.exit(training["global_step"] != int(sys.argv[2]) or training.get("base_weights_sha256") != weights_sha256(sys.argv[3]))' \
    "$1" "$2" "$STUDENT"
}

stage() {  # N RUN STEPS BUNDLE LOG CONFIG...: train (resuming) and export one stage
  local n=$1 run=$2 steps=$3 bundle=$4 log=$5; shift 5
  if [[ -n $only && $only != "$n" ]]; then return 0; fi
  if done_on_student "$bundle" "$steps"; then echo "train_controlnet.sh: stage $n done ($bundle)"; return 0; fi
  refuse_past train_controlnet.sh "$n" "$run" "$steps"
  echo "train_controlnet.sh: stage $n: $steps steps -> $bundle"
  fit_stage "$run" "$steps" "$@"
  "$STABLEMO" export "$run/checkpoints/last.ckpt" --out "$bundle" --overwrite
  "$PYTHON" scripts/train/training_log.py merge "$run/logs" "docs/data/control/$log"
}

# the path walks (docs/synth.md): 40 % of the clips replaced by walks along curved paths in any direction
[ -f data/synth_paths/Mean.npy ] || "$STABLEMO" data synth --out data/synth_paths --path-walks 0.4
[ -f data/synth/Mean.npy ] || "$STABLEMO" data synth --out data/synth --num 2000 --seed 0 --rest varied  # the student's statistics
stage 1 runs/controlnet_lcm_pelvis_toward 1500 bundles/demo_controlnet_toward controlnet_toward_training_log.csv \
  configs/control/controlnet_lcm_pelvis_floor.yaml configs/control/controlnet_lcm_pelvis_toward.yaml
stage 2 runs/controlnet_lcm_pelvis_toward_clip 1500 bundles/demo_controlnet_toward_clip controlnet_toward_clip_training_log.csv \
  configs/control/controlnet_lcm_pelvis_floor.yaml configs/control/controlnet_lcm_pelvis_toward.yaml \
  configs/control/pelvis_toward_clip.yaml
