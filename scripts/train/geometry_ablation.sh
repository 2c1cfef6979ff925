#!/usr/bin/env bash
# The geometric-loss ablation (issue #39, docs/training.md "Geometric losses"): the demo recipe
# (configs/demo.yaml) and the same recipe with MDM's geometric losses (+ configs/demo_geometry.yaml),
# trained side by side as two processes on one machine, then both exported as bundles.
#
#   scripts/train/geometry_ablation.sh ACCELERATOR STEPS OUT [fit overrides...]
#   scripts/train/geometry_ablation.sh gpu 6000 runs/geometry_ablation          # the real one
#   scripts/train/geometry_ablation.sh cpu 50 /tmp/geometry_smoke --data.batch_size=8
#
# ACCELERATOR: cpu or gpu. STEPS: optimiser steps of each run (the recipe:
# 6000). OUT: OUT/<variant>/ holds each run (checkpoints, logs, fit.log), OUT/bundles/<variant> its
# exported bundle, OUT/timings.csv each fit's wall time, OUT/val_loss.png both validation curves.
# Re-running continues each run from its last checkpoint. Relative paths (OUT, DATA) are taken from
# the repository root, where the script runs.
# Environment:
#   STABLEMO           the command (default .venv/bin/stablemo if present, else `python3 -m stablemo.cli`);
#   PYTHON             for the helper scripts (default .venv/bin/python if present, else python3);
#   DATA               data folder (default data/synth; made by `stablemo data synth` when absent);
#   VARIANTS           default "baseline geometry"; also "bones" (the geometry overlay plus bone_lengths 1);
#   THREADS            CPU threads of each run (default: the machine's cores shared between the runs);
#   PARALLEL=0         one run after the other (default: all at once);
#   COST_ROUNDS        paired rounds of scripts/train/geometry_step_cost.py afterwards (default 10; 0 skips);
#   EVAL_REPLICATIONS  >0: also `stablemo evaluate` each bundle on DATA (128 items per replication).
set -euo pipefail
cd "$(dirname "$0")/../.."
usage="usage: scripts/train/geometry_ablation.sh ACCELERATOR STEPS OUT [fit overrides...]"
[ $# -ge 3 ] || { echo "$usage" >&2; exit 2; }
accelerator=$1 steps=$2 out=$3
shift 3
case $accelerator in cpu | gpu) ;; *) echo "geometry_ablation.sh: ACCELERATOR: cpu or gpu, got '$accelerator'" >&2; exit 2 ;; esac
[[ $steps =~ ^[1-9][0-9]*$ ]] || { echo "geometry_ablation.sh: STEPS: a positive integer, got '$steps'" >&2; exit 2; }

if [ -n "${STABLEMO:-}" ]; then read -ra stablemo <<< "$STABLEMO"
elif [ -x .venv/bin/stablemo ]; then stablemo=(.venv/bin/stablemo)
else stablemo=(python3 -m stablemo.cli); fi
if [ -n "${PYTHON:-}" ]; then python=$PYTHON
elif [ -x .venv/bin/python ]; then python=.venv/bin/python
else python=python3; fi
data=${DATA:-data/synth}
read -ra variants <<< "${VARIANTS:-baseline geometry}"
cores=$(nproc)
threads=${THREADS:-$(( cores / ${#variants[@]} > 0 ? cores / ${#variants[@]} : 1 ))}
# the recipe validates every 500 steps and logs every 50; a shorter run does each once, at its end
validate_every=$(( steps < 500 ? steps : 500 ))
log_every=$(( steps < 50 ? steps : 50 ))

overlay() {  # VARIANT: its config files and flags on top of configs/demo.yaml, into `extra`
    case $1 in
        baseline) extra=() ;;
        geometry) extra=(--config configs/demo_geometry.yaml) ;;
        bones) extra=(--config configs/demo_geometry.yaml
                      "--model.geometry={positions: 1.0, velocities: 1.0, foot_contact: 1.0, bone_lengths: 1.0}") ;;
        *) return 1 ;;
    esac
}
for variant in "${variants[@]}"; do
    overlay "$variant" || { echo "geometry_ablation.sh: VARIANTS: unknown '$variant' (baseline, geometry, bones)" >&2; exit 2; }
done

[ -f "$data/Mean.npy" ] || "${stablemo[@]}" data synth --out "$data" --num 2000 --seed 0
mkdir -p "$out"

train() {  # VARIANT [fit overrides...]: one run, its wall time into OUT/VARIANT/seconds
    local variant=$1 dir=$out/$1 resume=() extra=()
    shift
    mkdir -p "$dir"
    [ -f "$dir/checkpoints/last.ckpt" ] && resume=(--ckpt_path last)
    overlay "$variant"
    local start=$SECONDS
    OMP_NUM_THREADS=$threads "${stablemo[@]}" fit --config configs/demo.yaml "${extra[@]}" \
        --trainer.accelerator="$accelerator" --trainer.max_steps="$steps" \
        --trainer.val_check_interval="$validate_every" --trainer.log_every_n_steps="$log_every" \
        --trainer.enable_progress_bar=false \
        --trainer.default_root_dir="$dir" --data.data_dir="$data" "${resume[@]}" "$@" > "$dir/fit.log" 2>&1
    echo $(( SECONDS - start )) > "$dir/seconds"
}

pids=()
for variant in "${variants[@]}"; do
    echo "training $variant: $steps steps on $accelerator, $threads threads (log: $out/$variant/fit.log)"
    if [ "${PARALLEL:-1}" = 0 ]; then
        train "$variant" "$@" || { tail -n 5 "$out/$variant/fit.log" >&2; exit 1; }
    else
        train "$variant" "$@" &
        pids+=($!)
    fi
done
failed=0
for i in "${!pids[@]}"; do
    if ! wait "${pids[$i]}"; then
        echo "geometry_ablation.sh: training ${variants[$i]} failed; the end of $out/${variants[$i]}/fit.log:" >&2
        tail -n 5 "$out/${variants[$i]}/fit.log" >&2
        failed=1
    fi
done
[ $failed = 0 ] || exit 1

echo "variant,steps,fit_seconds" > "$out/timings.csv.tmp"
for variant in "${variants[@]}"; do
    "${stablemo[@]}" export "$out/$variant/checkpoints/last.ckpt" --out "$out/bundles/$variant" --overwrite
    echo "$variant,$steps,$(cat "$out/$variant/seconds")" >> "$out/timings.csv.tmp"
done
mv "$out/timings.csv.tmp" "$out/timings.csv"
cat "$out/timings.csv"

labels=()
for variant in "${variants[@]}"; do labels+=("$variant=$out/$variant"); done
"$python" scripts/train/training_log.py plot --out "$out/val_loss.png" "${labels[@]}"

if [ "${COST_ROUNDS:-10}" -gt 0 ]; then
    cost_threads=()
    [ "$accelerator" = cpu ] && cost_threads=(--threads 1)  # CPU time per step is then the step's cost
    "$python" scripts/train/geometry_step_cost.py --data "$data" --accelerator "$accelerator" \
        --rounds "${COST_ROUNDS:-10}" "${cost_threads[@]}" --json "$out/step_cost.json"
fi

if [ "${EVAL_REPLICATIONS:-0}" -gt 0 ]; then
    for variant in "${variants[@]}"; do
        "${stablemo[@]}" evaluate --bundle "$out/bundles/$variant" --data "$data" --replications "$EVAL_REPLICATIONS" \
            --max-items 128 --skate-ratio --no-progress --out "$out/evaluate_$variant.json"
    done
fi
