# Sourced by the recipe scripts (train_demo.sh, train_controlnet.sh), after they cd to the repository
# root and set STABLEMO: the parts of one resumable training stage that every recipe shares.

# refuse_past SCRIPT N RUN STEPS: one line and exit 2 when RUN has a checkpoint past stage N's STEPS
# (it would be exported as it is, not at the stage's steps)
refuse_past() {
  local past
  past=$(ls "$3/checkpoints" 2>/dev/null | sed -n 's/.*step=\([0-9]*\)\.ckpt$/\1/p' | sort -n | tail -1) || true
  if [[ -n $past && $past -gt $4 ]]; then
    echo "$1: $3 has trained past stage $2's $4 steps (step $past); move it away to train the stage again" >&2
    exit 2
  fi
}

# fit_stage RUN STEPS CONFIG...: train the configs to STEPS, resuming RUN's last.ckpt when it has one
# (exactly: docs/training.md, "Checkpoints, resuming")
fit_stage() {
  local run=$1 steps=$2 c
  shift 2
  local resume=() configs=()
  [ -f "$run/checkpoints/last.ckpt" ] && resume=(--ckpt_path last)
  for c in "$@"; do configs+=(--config "$c"); done
  "$STABLEMO" fit "${configs[@]}" --trainer.max_steps="$steps" "${resume[@]}"
}
