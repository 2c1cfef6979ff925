#!/usr/bin/env bash
# Distil the bundled demo model into a consistency student and export it, in one command:
#   bash scripts/train/distill_demo.sh lcm|pcm [extra `stablemo fit` arguments]
# then: stablemo generate "a person jumps twice" --bundle bundles/demo_lcm --steps 1
# Uses configs/distill/<mode>_synth.yaml; re-running it resumes from the run's last checkpoint.
set -euo pipefail
cd "$(dirname "$0")/../.."
mode=${1:?usage: scripts/train/distill_demo.sh lcm|pcm [fit arguments]}
shift
case "$mode" in lcm|pcm) ;; *) echo "distill_demo.sh: mode must be lcm or pcm, got '$mode'" >&2; exit 2 ;; esac
STABLEMO=${STABLEMO:-.venv/bin/stablemo}
# data/synth holds the teacher's statistics; the students distil on the teacher's last clips
[ -f data/synth/Mean.npy ] || "$STABLEMO" data synth --out data/synth --num 2000 --seed 0 --rest varied
[ -f data/synth_16k_varied/Mean.npy ] ||
  "$STABLEMO" data synth --out data/synth_16k_varied --num 16000 --seed 2 --rest varied --captions varied
resume=()
[ -f "runs/distill_${mode}_synth/checkpoints/last.ckpt" ] && resume=(--ckpt_path last)
"$STABLEMO" fit --config "configs/distill/${mode}_synth.yaml" "${resume[@]}" "$@"
"$STABLEMO" export "runs/distill_${mode}_synth/checkpoints/last.ckpt" --out "bundles/demo_${mode}" --overwrite
