#!/usr/bin/env bash
# Recipe of the bundled demo model (stablemo/assets/demo_bundle): synthetic data, training with
# configs/demo.yaml, export, and a copy of the training log into docs/. Resumable: re-running it
# continues from runs/demo/checkpoints/last.ckpt. Then: scripts/train/distill_demo.sh lcm (the student)
# and scripts/train/ship_demo.sh (the student into the package; the length predictor and captions).
set -euo pipefail
cd "$(dirname "$0")/../.."
STABLEMO=${STABLEMO:-.venv/bin/stablemo}
[ -f data/synth/Mean.npy ] || "$STABLEMO" data synth --out data/synth --num 2000 --seed 0 --rest varied
# The next demo models train on clips with varied idle rest (docs/synth.md): a data/synth from before
# (the shipped models' data, no "rest" or "rest": "tight" in its synth.json) is not trained on silently.
grep -q '"rest": "varied"' data/synth/synth.json || {
  echo "train_demo.sh: data/synth was written without --rest varied; regenerate it (replaces it): $STABLEMO data synth --out data/synth --num 2000 --seed 0" >&2
  exit 2
}
resume=()
[ -f runs/demo/checkpoints/last.ckpt ] && resume=(--ckpt_path last)
"$STABLEMO" fit --config configs/demo.yaml "${resume[@]}" "$@"
# Guidance 1.5, not the paper's 2.5: chosen on the val split (scripts/results/cfg_sweep.py, docs/training.md
# "The demo teacher's guidance scale": FID 0.079 at 1.5 against 0.098 at 2.5, R@3 0.952 against 0.958)
"$STABLEMO" export runs/demo/checkpoints/last.ckpt --out stablemo/assets/demo_bundle --overwrite --cfg 1.5
.venv/bin/python scripts/train/training_log.py merge runs/demo/logs docs/data/training/demo_training_log.csv
