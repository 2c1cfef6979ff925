#!/usr/bin/env bash
# Recipe of the packaged evaluator of the synthetic benchmark (stablemo/assets/evaluator_synth,
# `stablemo evaluate`'s default on data written by `stablemo data synth`): synthetic data by seed,
# training with configs/evaluator_synth.yaml (400 steps, a few minutes on a CPU), export of the
# weights and statistics to a folder (config.json + model.safetensors, ~5 MB). Resumable.
set -euo pipefail
cd "$(dirname "$0")/../.."
STABLEMO=${STABLEMO:-.venv/bin/stablemo}
PYTHON=${PYTHON:-.venv/bin/python}
[ -f data/synth/Mean.npy ] || "$STABLEMO" data synth --out data/synth --num 2000 --seed 0
resume=()
[ -f runs/evaluator_synth/checkpoints/last.ckpt ] && resume=(--ckpt_path last)
"$STABLEMO" fit --config configs/evaluator_synth.yaml "${resume[@]}" "$@"
"$PYTHON" -c 'import sys; from stablemo.eval.evaluator import export_evaluator; print(export_evaluator(*sys.argv[1:]))' \
    runs/evaluator_synth/checkpoints/last.ckpt stablemo/assets/evaluator_synth
