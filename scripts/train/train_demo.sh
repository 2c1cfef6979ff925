#!/usr/bin/env bash
# Recipe of the bundled demo teacher (stablemo/assets/demo_bundle): three training stages on synthetic
# data, each starting from the previous stage's weights, all normalised with data/synth's statistics
# (docs/training.md, "The shipped demo teacher's recipe"):
#   1. configs/demo.yaml: 6000 steps on data/synth (2000 clips, seed 0)              -> bundles/demo_6000
#   2. + configs/demo_variants/further_more_data.yaml, 4000 steps on data/synth_8k (8000 clips, seed 1)
#                                                                                      -> bundles/demo_more_data_10000
#   3. + configs/demo_variants/further_16k_varied.yaml, 3000 steps on data/synth_16k_varied (16 000 clips
#      of seed 2, captioned in the wider vocabulary: --captions varied)               -> stablemo/assets/demo_bundle
# Resumable: re-running it skips the stages whose bundle holds their step count and continues the
# first unfinished one from its last.ckpt (exactly: docs/training.md, "Checkpoints, resuming"). About
# 0.8 s a step on the 2-core CPU alone: 80 + 55 + 40 min, plus the data (a few minutes).
#   bash scripts/train/train_demo.sh                # every stage
#   bash scripts/train/train_demo.sh --stage 1      # one stage (it needs the stages before it)
# Then: scripts/train/distill_demo.sh lcm (the student) and scripts/train/ship_demo.sh (the student into
# the package; the length predictor and the captions the unfamiliar-prompt warning reads).
set -euo pipefail
cd "$(dirname "$0")/../.."
STABLEMO=${STABLEMO:-.venv/bin/stablemo}
PYTHON=${PYTHON:-.venv/bin/python}
source scripts/train/stages.sh
only=
case "${1:-}" in
  "") ;;
  --stage) only=${2:-}; [[ $only =~ ^[123]$ ]] || { echo "train_demo.sh: --stage takes 1, 2 or 3, got '${2:-}'" >&2; exit 2; } ;;
  *) echo "train_demo.sh: unknown argument '$1' (usage: train_demo.sh [--stage 1|2|3])" >&2; exit 2 ;;
esac

data() {  # FOLDER ARGS...: write a synthetic dataset unless it is there
  local folder=$1; shift
  [ -f "$folder/Mean.npy" ] || "$STABLEMO" data synth --out "$folder" "$@"
}

done_at() {  # BUNDLE STEPS: does BUNDLE hold a network trained STEPS steps in its last stage?
  [ -f "$1/config.json" ] && "$PYTHON" -c 'import json, sys
sys.exit(json.load(open(sys.argv[1]))["training"]["global_step"] != int(sys.argv[2]))' "$1/config.json" "$2"
}

DATA=()  # the dataset the next stage trains on: FOLDER ARGS... of `stablemo data synth`

stage() {  # N RUN STEPS BUNDLE LOG CONFIG...: train (resuming) and export one stage, on DATA
  local n=$1 run=$2 steps=$3 bundle=$4 log=$5; shift 5
  if [[ -n $only && $only != "$n" ]]; then return 0; fi
  if done_at "$bundle" "$steps"; then echo "train_demo.sh: stage $n done ($bundle)"; return 0; fi
  refuse_past train_demo.sh "$n" "$run" "$steps"
  data "${DATA[@]}"
  echo "train_demo.sh: stage $n: ${steps} steps -> $bundle"
  fit_stage "$run" "$steps" "$@"
  # Guidance 1.5, not the paper's 2.5: chosen on the val split (scripts/results/cfg_sweep.py, docs/training.md
  # "The demo teacher's guidance scale")
  "$STABLEMO" export "$run/checkpoints/last.ckpt" --out "$bundle" --overwrite --cfg 1.5
  "$PYTHON" scripts/train/training_log.py merge "$run/logs" "docs/data/training/$log"
}

# data/synth holds every stage's statistics. The demo models train on clips with varied idle rest
# (docs/synth.md): a data/synth from before (no "rest" or "rest": "tight" in its synth.json) is not
# trained on silently.
data data/synth --num 2000 --seed 0 --rest varied
grep -q '"rest": "varied"' data/synth/synth.json || {
  echo "train_demo.sh: data/synth was written without --rest varied; regenerate it (replaces it): $STABLEMO data synth --out data/synth --num 2000 --seed 0" >&2
  exit 2
}
DATA=(data/synth --num 2000 --seed 0 --rest varied)
stage 1 runs/demo 6000 bundles/demo_6000 demo_training_log.csv configs/demo.yaml
DATA=(data/synth_8k --num 8000 --seed 1 --rest varied)
stage 2 runs/demo_further_more_data 4000 bundles/demo_more_data_10000 demo_more_data_training_log.csv \
  configs/demo.yaml configs/demo_variants/further_more_data.yaml
DATA=(data/synth_16k_varied --num 16000 --seed 2 --rest varied --captions varied)
stage 3 runs/demo_further_16k_varied 3000 stablemo/assets/demo_bundle demo_16k_varied_training_log.csv \
  configs/demo.yaml configs/demo_variants/further_16k_varied.yaml
