#!/usr/bin/env bash
# Regenerate every table and picture in the docs that depends on the shipped demo models (the teacher
# stablemo/assets/demo_bundle, the 1-step student stablemo/assets/demo_student, the ControlNet
# stablemo/assets/demo_controlnet), in one command, right after new demo models were shipped by
#   bash scripts/train/train_demo.sh && bash scripts/train/distill_demo.sh lcm && bash scripts/train/ship_demo.sh &&
#     bash scripts/train/train_controlnet.sh && bash scripts/train/ship_demo.sh   # the ControlNet on the student just shipped
#
#   bash scripts/results/after_ship.sh              # every step, in order
#   bash scripts/results/after_ship.sh --dry-run    # print the commands, run nothing
#   bash scripts/results/after_ship.sh --list       # the step names (and the docs section each refreshes)
#   bash scripts/results/after_ship.sh --from STEP  # start at STEP (resume an interrupted run)
#   bash scripts/results/after_ship.sh --to STEP    # stop after STEP (with --from: a range of steps)
#   bash scripts/results/after_ship.sh --skip STEP  # leave STEP out (repeatable)
#
# Each step runs the command its docs section gives (same options, same output paths) and logs to
# outputs/after_ship/logs/STEP.log (AFTER_SHIP_DIR moves outputs/after_ship). Partial outputs that the
# docs keep only merged or renamed (the joint-control runs, the streamed-prompt reports) go under
# outputs/after_ship/ first; tables that a script only prints (footskate/report.py, bvh/report.py,
# length_count_check.py, segment_parts.py, the heading checks at constant speed, the benchmarks, the
# errors printed by the example scripts) are in those logs, to be copied into the docs by hand.
# Before anything runs, the prerequisites of the chosen steps are checked (data, bundles, Blender,
# Chromium, ...); a missing one is named with the one-line command that makes it, and the script exits 2.
#
# It takes many hours on the 2-core CPU (most of a day: make_results.py and the joint-control
# reports alone take hours); --from resumes after an interruption.
#
# Afterwards the prose must still be read and updated by hand: only docs/results.md (through
# make_results.py and behaviour_report.py), the pictures and the files under docs/data/ are rewritten.
# Numbers quoted in text, and tables typed into the docs from printed output or from a JSON, are in:
#   README.md               the double jump's length and count ("a double jump 3.2 s, two jumps")
#   docs/results.md         the notes above the joint-control tables (the date measured, the AITS ratios
#                           "teacher 1.21x, student 1.25x") live in scripts/results/make_results.py
#                           (CONTROL_TABLES), the behaviour section's fixed text in stablemo/eval/behaviour/report.py
#   docs/inference.md       the finishing step's measured effect (kinematics.json), the length-from-text table
#                           (length_count_check.py), "Prompts in parts" (behaviour JSONs, the README picture's
#                           description), the counts-by-repetition and held-apart composite runs, "Turns
#                           as said" (the behaviour before/after and turns/turns.md's numbers)
#   docs/evaluation.md      "What the demo models get wrong" and the behaviour runs' times (behaviour JSONs)
#   docs/control.md         the heading tables (heading_*.json, logs; the shipped ControlNet's: heading_controlnet_toward_*.json), the control table's "What it says", the
#                           ControlNet tables, its targets table and prose (controlnet_results.json, bench aits),
#                           the examples' and controlnet_example.py's printed errors, the speed table
#   docs/training.md        the guidance-scale table and prose (cfg_sweep_val.json), the shipped row of
#                           "Behaviour against size and training time" (benchmark_demo_teacher_tight.json,
#                           behaviour_teacher.json), the shipped column of the mid_attention table
#   docs/distillation.md    the students' FID and AITS ratios quoted from docs/results.md
#   docs/long_motion.md     every table (report.py, stream_prompts, segment_parts, bench stream; logs and
#                           docs/data/long_motion/) and the turn-context prose (turn_context*/report.md)
#   docs/footskate.md       the demo table (footskate/report.py log) and the two examples' numbers
#   docs/bvh.md             the demo rows of the measured table (bvh/report.py log)
#   docs/retarget.md        the demo walk's rows and sentences (docs/data/retarget/measure.json)
#   docs/serve.md           "The demo student" (what it does with "a person jumps, then turns left")
#   docs/gltf.md            the pictures' captions
set -euo pipefail
cd "$(dirname "$0")/../.."
PYTHON=${PYTHON:-.venv/bin/python}
STABLEMO=${STABLEMO:-.venv/bin/stablemo}
WORK=${AFTER_SHIP_DIR:-outputs/after_ship}
DRY=0

# ------------------------------------------------------------------------------------- helpers

quote() {  # the command as one line a shell reads back
  local out=() a
  for a in "$@"; do
    if [[ $a == *$'\n'* ]]; then out+=("'<inline Python: see scripts/results/after_ship.sh>'")
    elif [[ $a =~ ^[A-Za-z0-9_./=:,%+@-]+$ ]]; then out+=("$a")
    else out+=("'${a//\'/\'\\\'\'}'"); fi
  done
  echo "${out[*]}"
}

run() {  # print the command; run it unless --dry-run
  if [[ $DRY == 1 ]]; then quote "$@"; return 0; fi
  echo "+ $(quote "$@")"
  "$@"
}

STEPS=()
declare -A NEEDS=() DOC=()
step() { STEPS+=("$1"); NEEDS[$1]=$2; DOC[$1]=$3; }  # NAME "PREREQUISITES" "docs section"

# ------------------------------------------------------------------- docs/results.md and its JSON

# docs/results.md "Kinematic measures" (rendered by make_results.py); docs/inference.md "The finishing step"
step kinematics "shipped" "docs/results.md: Kinematic measures; docs/inference.md: The finishing step"
step_kinematics() { run "$PYTHON" scripts/results/kinematic_report.py --summary docs/data/results/kinematics.json; }

# docs/results.md "Behaviour" (the runs; the ground-truth column does not depend on the models and is kept)
BEHAVIOUR=(--seeds 4 --lengths default natural 6 9.8)
step behaviour_teacher "shipped" "docs/results.md: Behaviour (teacher column)"
step_behaviour_teacher() { run "$STABLEMO" behaviour --bundle stablemo/assets/demo_bundle "${BEHAVIOUR[@]}" --out docs/data/results/behaviour_teacher.json; }
step behaviour_student "shipped" "docs/results.md: Behaviour (1-step student column)"
step_behaviour_student() { run "$STABLEMO" behaviour --bundle stablemo/assets/demo_student "${BEHAVIOUR[@]}" --out docs/data/results/behaviour_student.json; }
step behaviour_teacher_whole "shipped" "docs/results.md: Behaviour (teacher, whole); docs/training.md: mid_attention table"
step_behaviour_teacher_whole() { run "$STABLEMO" behaviour --bundle stablemo/assets/demo_bundle "${BEHAVIOUR[@]}" --whole --out docs/data/results/behaviour_teacher_whole.json; }
step behaviour_student_whole "shipped" "docs/results.md: Behaviour (1-step student, whole)"
step_behaviour_student_whole() { run "$STABLEMO" behaviour --bundle stablemo/assets/demo_student "${BEHAVIOUR[@]}" --whole --out docs/data/results/behaviour_student_whole.json; }

# docs/results.md "Behaviour": the section and docs/data/results/behaviour.png from the JSON above
step behaviour_report "" "docs/results.md: Behaviour (section and behaviour.png)"
step_behaviour_report() { run "$PYTHON" scripts/results/behaviour_report.py; }

# docs/results.md "Joint control by guidance" and docs/control.md "Results": two report.py runs and two
# `stablemo evaluate ... --footskate` rows, merged into docs/data/results/results_control.json by control_merge
step control_teacher "shipped synth" "docs/results.md: Joint control by guidance (teacher rows); docs/control.md: Results"
step_control_teacher() { run "$PYTHON" scripts/control/report.py --replications 3 --max-items 96 --out "$WORK/control/ctl_teacher.json"; }
step control_student "shipped synth" "docs/results.md: Joint control by guidance (student rows); docs/control.md: Results"
step_control_student() { run "$PYTHON" scripts/control/report.py --replications 3 --max-items 96 --no-teacher --student LCM=stablemo/assets/demo_student --out "$WORK/control/ctl_student.json"; }
FOOTSKATE_ROW=(--data data/synth --replications 3 --max-items 96 --control pelvis --density 100% --footskate)
step control_footskate_teacher "shipped synth" "docs/results.md: Joint control by guidance (teacher + --footskate row)"
step_control_footskate_teacher() { run "$STABLEMO" evaluate --bundle stablemo/assets/demo_bundle "${FOOTSKATE_ROW[@]}" --out "$WORK/control/footskate_teacher.json"; }
step control_footskate_student "shipped synth" "docs/results.md: Joint control by guidance (student + --footskate row)"
step_control_footskate_student() { run "$STABLEMO" evaluate --bundle stablemo/assets/demo_student "${FOOTSKATE_ROW[@]}" --out "$WORK/control/footskate_student.json"; }

# The committed results_control.json's layout: the teacher's rows, then the student's, each model's
# "pelvis 100% + --footskate" row after its "pelvis 100%" row; settings of both runs; AITS of both.
MERGE_CONTROL='
import json, sys
from pathlib import Path
teacher, student, fs_teacher, fs_student, out = sys.argv[1:]
load = lambda p: json.loads(Path(p).read_text())
runs = [load(teacher), load(student)]
footskate = {}
for run, path in zip(runs, (fs_teacher, fs_student)):
    rows = load(path)["rows"]
    keys = [k for k in rows if k != "Real motion" and not k.endswith(" [raw]")]
    if len(keys) != 1:
        sys.exit(f"{path}: expected one model row besides the raw and real ones, found {keys}")
    footskate[next(iter(run["rows"])).split(" | ")[0]] = {"model": rows[keys[0]]}
rows = {}
for run in runs:
    for key, row in run["rows"].items():
        rows[key] = row
        model, control = key.split(" | ")
        if control == "pelvis 100%":
            rows[f"{model} | pelvis 100% + --footskate"] = footskate.pop(model)
if footskate:
    sys.exit(f"no pelvis 100% row for {sorted(footskate)}")
settings = {"teacher": runs[0]["settings"], "student": runs[1]["settings"],
            "footskate_rows": "stablemo evaluate --bundle B --data data/synth --replications 3 --max-items 96 "
                              "--control pelvis --density 100% --footskate",
            "footskate_rows_measured": "B = stablemo/assets/demo_bundle and stablemo/assets/demo_student, right after the other rows",
            "replications": runs[0]["settings"]["replications"], "max_items": runs[0]["settings"]["max_items"]}
Path(out).write_text(json.dumps({"settings": settings, "rows": rows, "aits": {**runs[0]["aits"], **runs[1]["aits"]}}, indent=2) + "\n")
print(f"wrote {out}: {len(rows)} rows")
'
step control_merge "file:$WORK/control/ctl_teacher.json:control_teacher file:$WORK/control/ctl_student.json:control_student file:$WORK/control/footskate_teacher.json:control_footskate_teacher file:$WORK/control/footskate_student.json:control_footskate_student" \
    "docs/results.md: Joint control by guidance (docs/data/results/results_control.json)"
step_control_merge() {
  run "$PYTHON" -c "$MERGE_CONTROL" "$WORK/control/ctl_teacher.json" "$WORK/control/ctl_student.json" \
      "$WORK/control/footskate_teacher.json" "$WORK/control/footskate_student.json" docs/data/results/results_control.json
}

# docs/results.md "Motion ControlNet on the 1-step student"; docs/control.md "What the shipped one reaches"
CONTROLNET=(--no-teacher --student LCM=stablemo/assets/demo_student --controlnet "LCM 1-step=stablemo/assets/demo_controlnet")
step controlnet_results "shipped controlnet synth" "docs/results.md: Motion ControlNet on the 1-step student; docs/control.md: ControlNet tables"
step_controlnet_results() { run "$PYTHON" scripts/control/report.py "${CONTROLNET[@]}" --rows none:100%,pelvis:100%,pelvis:25%,pelvis:5,pelvis:1 --replications 3 --max-items 96 --out docs/data/results/controlnet_results.json; }
# docs/results.md "Facing along hinted paths" (body steered) and its A/B "the same with the facing left to the network"
step control_facing "shipped controlnet synth" "docs/results.md: Facing along hinted paths (body steered)"
step_control_facing() { run "$PYTHON" scripts/control/report.py "${CONTROLNET[@]}" --rows none:100%,pelvis:100%,pelvis:5 --replications 2 --max-items 64 --out docs/data/results/control_facing.json; }
step control_facing_unsteered "shipped controlnet synth" "docs/results.md: Facing along hinted paths, facing left to the network"
step_control_facing_unsteered() { run "$PYTHON" scripts/control/report.py "${CONTROLNET[@]}" --rows none:100%,pelvis:100%,pelvis:5 --replications 2 --max-items 64 --no-face-travel --out docs/data/results/control_facing_unsteered.json; }

# docs/results.md, all of it: samplers, students, bf16, then the sections above from their JSON (last, so it
# renders the fresh ones); --resume rescores every row whose bundle changed (bundles/demo_lcm, bundles/demo_pcm);
# --ddpm-replications 1: Table 5's 1000-step DDPM row beside the 10-step SDE row (96 items, one replication)
step make_results "shipped synth_tight lcm pcm" "docs/results.md: every table (samplers, students, bf16; re-renders the sections above)"
step_make_results() { run env OMP_NUM_THREADS=1 "$PYTHON" scripts/results/make_results.py --no-distill --resume --replications 10 --ddpm-replications 1; }

# ------------------------------------------------------------------------------- docs/inference.md

# docs/inference.md "Prompts in parts": docs/data/results/readme_prompt.png
step readme_prompt "shipped" "docs/inference.md: Prompts in parts (readme_prompt.png)"
step_readme_prompt() { run "$PYTHON" scripts/results/readme_prompt_picture.py; }
# docs/inference.md "Turns as said": docs/data/results/turns/ (turns.json, turns.md, turns.png); the
# numbers in its prose are typed from turns.md
step turn_report "shipped" "docs/inference.md: Turns as said (turns/: table and picture)"
step_turn_report() { run "$PYTHON" scripts/results/turn_report.py --out docs/data/results/turns; }
# docs/inference.md "How long a motion is": the jump-count table (printed; log)
step length_count "shipped" "docs/inference.md: How long a motion is (table, printed)"
step_length_count() { run "$PYTHON" scripts/text/length_count_check.py; }

# -------------------------------------------------------------------------------- docs/training.md

# docs/training.md "The demo teacher's guidance scale": docs/data/training/cfg_sweep_val.json
step cfg_sweep "shipped synth" "docs/training.md: The demo teacher's guidance scale"
step_cfg_sweep() { run "$PYTHON" scripts/results/cfg_sweep.py --bundle stablemo/assets/demo_bundle --data data/synth --cfg 1.0 1.5 2.0 2.5 --out docs/data/training/cfg_sweep_val.json; }
# docs/training.md "Behaviour against size and training time": the shipped teacher's benchmark row
step teacher_tight "shipped synth_tight" "docs/training.md: Behaviour against size and training time (shipped row)"
step_teacher_tight() { run "$STABLEMO" evaluate --bundle stablemo/assets/demo_bundle --data data/synth_tight --max-items 128 --replications 3 --out docs/data/training/benchmark_demo_teacher_tight.json; }

# --------------------------------------------------------------------------------- docs/control.md

# docs/control.md "Results": the example strips (pelvis_dense.png ... upper_body.png; errors printed)
step control_examples "shipped synth" "docs/control.md: Results (example pictures)"
step_control_examples() { run "$PYTHON" scripts/control/examples.py --out docs/data/control; }
# docs/control.md "How it works": docs/data/control/heading.png
step heading_picture "shipped" "docs/control.md: A path turns the body (heading.png)"
step_heading_picture() { run "$PYTHON" scripts/control/heading_picture.py; }

# docs/control.md "A drawn path is walked at the pace of the motion on screen" and the ControlNet heading table
HEADING=(--paths 3 --rng 200 --seeds 0,1,2,3)
step heading_student "shipped" "docs/control.md: pace table, student (heading_student_guided.json)"
step_heading_student() { run "$PYTHON" scripts/control/heading_check.py --model student "${HEADING[@]}" --json docs/data/control/heading_student_guided.json; }
step heading_teacher "shipped" "docs/control.md: pace table, teacher at its guidance (heading_teacher_cfg1.5.json)"
step_heading_teacher() { run "$PYTHON" scripts/control/heading_check.py --model teacher "${HEADING[@]}" --json docs/data/control/heading_teacher_cfg1.5.json; }
# the shipped ControlNet's heading table (docs/control.md, "The shipped ControlNet ... steps toward the next
# target"): the paths above, held-out ones, a third set, and two other gaits
CN_TABLE="docs/control.md: the shipped ControlNet's heading table"
CN_HELDOUT=(--paths 3 --rng 300 --seeds 4,5,6,7)
CN_THIRD=(--paths 3 --rng 400 --seeds 8,9,10,11)
step heading_controlnet "shipped controlnet" "$CN_TABLE, alone, and unsteered by --ab (heading_controlnet_toward_alone.json)"
step_heading_controlnet() { run "$PYTHON" scripts/control/heading_check.py --model controlnet --no-guidance --ab "${HEADING[@]}" --json docs/data/control/heading_controlnet_toward_alone.json; }
step heading_controlnet_guided "shipped controlnet" "$CN_TABLE, + guidance (heading_controlnet_toward_guided.json)"
step_heading_controlnet_guided() { run "$PYTHON" scripts/control/heading_check.py --model controlnet "${HEADING[@]}" --json docs/data/control/heading_controlnet_toward_guided.json; }
step heading_controlnet_heldout "shipped controlnet" "$CN_TABLE, held-out paths alone (heading_controlnet_toward_heldout_alone.json)"
step_heading_controlnet_heldout() { run "$PYTHON" scripts/control/heading_check.py --model controlnet --no-guidance "${CN_HELDOUT[@]}" --json docs/data/control/heading_controlnet_toward_heldout_alone.json; }
step heading_controlnet_heldout_guided "shipped controlnet" "$CN_TABLE, held-out paths + guidance (heading_controlnet_toward_heldout_guided.json)"
step_heading_controlnet_heldout_guided() { run "$PYTHON" scripts/control/heading_check.py --model controlnet "${CN_HELDOUT[@]}" --json docs/data/control/heading_controlnet_toward_heldout_guided.json; }
step heading_controlnet_third "shipped controlnet" "$CN_TABLE, the third set (heading_controlnet_toward_third_{alone,guided}.json)"
step_heading_controlnet_third() {
  run "$PYTHON" scripts/control/heading_check.py --model controlnet --no-guidance "${CN_THIRD[@]}" --json docs/data/control/heading_controlnet_toward_third_alone.json
  run "$PYTHON" scripts/control/heading_check.py --model controlnet "${CN_THIRD[@]}" --json docs/data/control/heading_controlnet_toward_third_guided.json
}
step heading_controlnet_gaits "shipped controlnet" "$CN_TABLE, other gaits alone (heading_controlnet_toward_{backwards,sidesteps}_alone.json)"
step_heading_controlnet_gaits() {
  run "$PYTHON" scripts/control/heading_check.py --model controlnet --no-guidance --texts "a person walks backwards" "${HEADING[@]}" --json docs/data/control/heading_controlnet_toward_backwards_alone.json
  run "$PYTHON" scripts/control/heading_check.py --model controlnet --no-guidance --texts "a person side steps to the left" "${HEADING[@]}" --json docs/data/control/heading_controlnet_toward_sidesteps_alone.json
}
# docs/control.md pace table, the "constant speed" side of its last column (printed; log)
step heading_constant "shipped" "docs/control.md: pace table, constant-speed column (printed)"
step_heading_constant() {
  run "$PYTHON" scripts/control/heading_check.py --model student "${HEADING[@]}" --timing constant
  run "$PYTHON" scripts/control/heading_check.py --model teacher "${HEADING[@]}" --timing constant
}
# docs/control.md "Measured on drawn paths": the first heading table (2 seeds, steered and not; backwards,
# side steps); its JSON held the models before the input head until this reruns them on the shipped ones
step heading_first_table "shipped" "docs/control.md: Measured on drawn paths (first heading table)"
step_heading_first_table() {
  local hc=("$PYTHON" scripts/control/heading_check.py --paths 3 --rng 200 --seeds 0,1)
  local turns=(--families arc,s_curve,out_and_back)
  run "${hc[@]}" --model student --texts "a person walks forward|the man walks slowly" --ab --json docs/data/control/heading_student.json
  run "${hc[@]}" --model teacher --ab --json docs/data/control/heading_teacher.json
  run "${hc[@]}" --model student --texts "a person walks backwards" "${turns[@]}" --json docs/data/control/heading_backwards_student.json
  run "${hc[@]}" --model teacher --texts "a person walks backwards" "${turns[@]}" --json docs/data/control/heading_backwards_teacher.json
  run "${hc[@]}" --model student --texts "a person side steps to the left" "${turns[@]}" --speed 0.45 --json docs/data/control/heading_sidesteps_student.json
}

# docs/control.md "Motion ControlNet": controlnet_free.png, controlnet_controlnet.png, controlnet_controlnet_guided.png
step controlnet_example "shipped controlnet synth" "docs/control.md: Motion ControlNet (the three strips; errors printed)"
step_controlnet_example() { run "$PYTHON" scripts/control/controlnet_example.py; }
# docs/control.md "Speed" table (the shipped controlled student's row) and the targets table's AITS (printed)
step controlnet_aits "shipped controlnet" "docs/control.md: Speed (shipped controlled student) and targets table (printed)"
step_controlnet_aits() {
  run "$STABLEMO" bench aits --bundle stablemo/assets/demo_controlnet --repeats 5 --threads 1
  run "$STABLEMO" bench aits --bundle stablemo/assets/demo_controlnet --frames 120 --repeats 15 --threads 1
}

# ------------------------------------------------------------------------------- docs/footskate.md

# docs/footskate.md "On the demo model's generations": the table (printed; log)
step footskate_report "shipped" "docs/footskate.md: On the demo model's generations (table, printed)"
step_footskate_report() { run "$PYTHON" scripts/footskate/report.py; }
# docs/footskate.md: docs/data/footskate/run_feet.png, jump_feet.png (numbers printed)
step footskate_examples "shipped" "docs/footskate.md: the two prompts (run_feet.png, jump_feet.png)"
step_footskate_examples() { run "$PYTHON" scripts/footskate/examples.py; }

# ----------------------------------------------------------------------------- docs/long_motion.md

# docs/long_motion.md "Timelines": example_segments.png, example_path.png, example.gif
step long_motion_examples "shipped" "docs/long_motion.md: the example timeline (pictures, gif)"
step_long_motion_examples() { run "$PYTHON" scripts/long_motion/examples.py --out docs/data/long_motion --gif; }
# docs/long_motion.md "Choosing overlap, blend and settle" and "Does each segment do what its text says?"
# (report.md and report.json under outputs/after_ship/long_motion/report)
step long_motion_report "shipped synth" "docs/long_motion.md: Choosing overlap, blend and settle; Does each segment do what its text says?"
step_long_motion_report() { run "$PYTHON" scripts/long_motion/report.py --out "$WORK/long_motion/report"; }

# docs/long_motion.md "Streaming a timeline by whole prompts": docs/data/long_motion/stream_prompts/NAME.{json,md}
stream_prompts() {  # NAME [stream_prompts.py options]: the script writes OUT/report.{json,md}; the docs keep NAME.{json,md}
  local name=$1; shift
  run "$PYTHON" scripts/long_motion/stream_prompts.py "$@" --out "$WORK/stream_prompts/$name"
  run cp "$WORK/stream_prompts/$name/report.json" "docs/data/long_motion/stream_prompts/$name.json"
  run cp "$WORK/stream_prompts/$name/report.md" "docs/data/long_motion/stream_prompts/$name.md"
}
step stream_prompts_student "shipped" "docs/long_motion.md: Streaming a timeline by whole prompts (student)"
step_stream_prompts_student() { stream_prompts student; }
step stream_prompts_student_whole "shipped" "docs/long_motion.md: Streaming a timeline by whole prompts (student, whole)"
step_stream_prompts_student_whole() { stream_prompts student_whole --whole; }
step stream_prompts_teacher "shipped" "docs/long_motion.md: Streaming a timeline by whole prompts (teacher)"
step_stream_prompts_teacher() { stream_prompts teacher --bundle stablemo/assets/demo_bundle; }
step stream_prompts_teacher_whole "shipped" "docs/long_motion.md: Streaming a timeline by whole prompts (teacher, whole)"
step_stream_prompts_teacher_whole() { stream_prompts teacher_whole --bundle stablemo/assets/demo_bundle --whole; }
# docs/long_motion.md, the streamed-turn shortfall: turn_context/report.md (4-s windows) and turn_context_2s (2 s)
step turn_context "shipped" "docs/long_motion.md: turn shortfall, 4-s windows (turn_context/)"
step_turn_context() { run "$PYTHON" scripts/long_motion/turn_context.py --bundle stablemo/assets/demo_bundle --out docs/data/long_motion/turn_context; }
step turn_context_2s "shipped" "docs/long_motion.md: turn shortfall, 2-s window (turn_context_2s/)"
step_turn_context_2s() { run "$PYTHON" scripts/long_motion/turn_context.py --bundle stablemo/assets/demo_bundle --texts "a person turns left" --new 40 --out docs/data/long_motion/turn_context_2s; }
# docs/long_motion.md "Segments in parts": the table (printed; log)
step segment_parts "shipped" "docs/long_motion.md: Segments in parts (table, printed)"
step_segment_parts() { run "$PYTHON" scripts/long_motion/segment_parts.py; }
# docs/long_motion.md "Streaming: cost and 10 minutes of drift": the cost table (printed; log)
step stream_bench "shipped" "docs/long_motion.md: Streaming: cost (table, printed)"
step_stream_bench() { run env OMP_NUM_THREADS=1 "$STABLEMO" bench stream --chunks 30; }

# ---------------------------------------------------------------------- docs/bvh.md, retarget, glTF

# docs/bvh.md "Measured": the demo model's and student's rows (printed; log)
step bvh_report "shipped blender hml3d" "docs/bvh.md: Measured (demo rows, printed)"
step_bvh_report() { run env OMP_NUM_THREADS=1 "$PYTHON" scripts/bvh/report.py; }
# docs/retarget.md "Measured": docs/data/retarget/measure.json (the demo model walk's rows) and retarget.png
step retarget_measure "shipped blender hml3d" "docs/retarget.md: Measured (measure.json, retarget.png)"
step_retarget_measure() { run env OMP_NUM_THREADS=1 "$PYTHON" scripts/retarget/measure.py; }
# docs/gltf.md: blender.png (the teacher's README prompt in Blender), page_body.png and page_rest.png (the page, student)
step gltf_pictures "shipped blender chromium three pymods" "docs/gltf.md: blender.png, page_body.png, page_rest.png"
step_gltf_pictures() { run "$PYTHON" scripts/gltf/pictures.py; }

# --------------------------------------------------------------------------------- prerequisites

CONTROLNET_BASE='
import sys, torch
from safetensors import safe_open
net, student = safe_open(sys.argv[1], "pt"), safe_open(sys.argv[2], "pt")
keys = set(net.keys())
same = all("base." + k in keys and torch.equal(net.get_tensor("base." + k), student.get_tensor(k)) for k in student.keys())
sys.exit(0 if same else 1)
'
# DERIVED TEACHER: exit 0 when the student bundle DERIVED records TEACHER's weights as its teacher
# (training.teacher_weights_sha256, written by distillation), 1 when it records other weights, 3 when
# it records none (a student distilled before the record existed: the caller falls back to file times)
DISTILLED_FROM='
import json, sys
from pathlib import Path
from stablemo.inference.bundle import weights_sha256
recorded = json.loads((Path(sys.argv[1]) / "config.json").read_text()).get("training", {}).get("teacher_weights_sha256")
if recorded is None:
    sys.exit(3)
sys.exit(0 if recorded == weights_sha256(sys.argv[2]) else 1)
'
# distilled_from DERIVED TEACHER: true unless DERIVED was distilled from other weights than TEACHER's
# (by its record, or without one by file time: older than the teacher)
distilled_from() {
  local rc=0
  "$PYTHON" -c "$DISTILLED_FROM" "$1" "$2" || rc=$?
  case $rc in
    0) return 0 ;;
    3) [[ ! $1/model.safetensors -ot $2/model.safetensors ]] ;;
    *) return 1 ;;
  esac
}
PROBLEMS=()
declare -A CHECKED=()
problem() { local p; for p in "${PROBLEMS[@]}"; do [[ $p == "$1" ]] && return 0; done; PROBLEMS+=("$1"); }

check() {  # KEY: one prerequisite; adds a line "what is missing: the command that makes it" to PROBLEMS
  [[ -n ${CHECKED[$1]:-} ]] && return 0
  CHECKED[$1]=1
  local b f
  case $1 in
    synth) [[ -f data/synth/Mean.npy ]] || problem "data/synth is missing: $STABLEMO data synth --out data/synth --num 2000 --seed 0 --rest varied" ;;
    synth_tight) [[ -f data/synth_tight/Mean.npy ]] || problem "data/synth_tight is missing: $STABLEMO data synth --out data/synth_tight --num 2000 --seed 0 --rest tight" ;;
    shipped)
      [[ -x $PYTHON ]] || problem "$PYTHON is missing: bash scripts/setup.sh"
      [[ -x $STABLEMO ]] || problem "$STABLEMO is missing: bash scripts/setup.sh"
      [[ -f stablemo/assets/demo_student/model.safetensors ]] || problem "stablemo/assets/demo_student is missing: bash scripts/train/distill_demo.sh lcm && bash scripts/train/ship_demo.sh"
      for b in demo_bundle demo_student demo_controlnet; do
        for f in config.json model.safetensors length.safetensors familiar.safetensors; do
          [[ -f stablemo/assets/$b/$f ]] || problem "stablemo/assets/$b/$f is missing (the length predictor and captions come last): bash scripts/train/ship_demo.sh"
        done
      done
      if [[ -f stablemo/assets/demo_student/model.safetensors && -f stablemo/assets/demo_bundle/model.safetensors ]] &&
         ! distilled_from stablemo/assets/demo_student stablemo/assets/demo_bundle; then
        echo "after_ship.sh: warning: stablemo/assets/demo_student was not distilled from the shipped teacher (by its record of the teacher's weights, or older than it where it has none) (bash scripts/train/distill_demo.sh lcm && bash scripts/train/ship_demo.sh)" >&2
      fi ;;
    controlnet)
      if [[ -f stablemo/assets/demo_controlnet/model.safetensors && -f stablemo/assets/demo_student/model.safetensors ]] &&
         ! "$PYTHON" -c "$CONTROLNET_BASE" stablemo/assets/demo_controlnet/model.safetensors stablemo/assets/demo_student/model.safetensors; then
        problem "stablemo/assets/demo_controlnet was trained on another student than stablemo/assets/demo_student (move runs/controlnet_lcm_pelvis_toward and runs/controlnet_lcm_pelvis_toward_clip away first): bash scripts/train/train_controlnet.sh && bash scripts/train/ship_demo.sh"
      fi ;;
    lcm)
      [[ -f bundles/demo_lcm/config.json ]] || problem "bundles/demo_lcm is missing: bash scripts/train/distill_demo.sh lcm"
      if [[ -f bundles/demo_lcm/model.safetensors && -f stablemo/assets/demo_student/model.safetensors ]] &&
         ! cmp -s bundles/demo_lcm/model.safetensors stablemo/assets/demo_student/model.safetensors; then
        echo "after_ship.sh: warning: bundles/demo_lcm is not the shipped student's weights (docs/results.md scores bundles/demo_lcm): bash scripts/train/distill_demo.sh lcm && bash scripts/train/ship_demo.sh" >&2
      fi ;;
    pcm)
      [[ -f bundles/demo_pcm/config.json ]] || problem "bundles/demo_pcm is missing: bash scripts/train/distill_demo.sh pcm"
      if [[ -f bundles/demo_pcm/model.safetensors && -f stablemo/assets/demo_bundle/model.safetensors ]] &&
         ! distilled_from bundles/demo_pcm stablemo/assets/demo_bundle; then
        echo "after_ship.sh: warning: bundles/demo_pcm was not distilled from the shipped teacher (by its record of the teacher's weights, or older than it where it has none), so docs/results.md's PCM rows would be an earlier teacher's student (move runs/distill_pcm_synth away, then: bash scripts/train/distill_demo.sh pcm)" >&2
      fi ;;
    blender) command -v blender >/dev/null || problem "blender is not on PATH: apt-get install blender" ;;
    chromium)
      { command -v chromium >/dev/null || command -v chromium-browser >/dev/null; } && command -v chromedriver >/dev/null ||
        problem "chromium and chromedriver are not both on PATH: apt-get install chromium chromium-driver" ;;
    three) [[ -f stablemo/serve/static/vendor/three/three.module.js ]] || problem "three.js is not vendored: $STABLEMO vendor three" ;;
    pymods)
      "$PYTHON" -c 'import importlib.util as u, sys; sys.exit(any(u.find_spec(m) is None for m in ("selenium", "fastapi", "uvicorn")))' ||
        problem "selenium, fastapi or uvicorn is not installed: bash scripts/setup.sh" ;;
    hml3d)
      for f in new_joints/012314.npy new_joint_vecs/012314.npy; do
        [[ -f ../shared/data/humanml3d-sample/$f ]] || problem "../shared/data/humanml3d-sample/$f is missing (the real HumanML3D clip of the table; not made by any command here: copy the shared HumanML3D sample there)"
      done ;;
    file:*)  # file:PATH:STEP: made by STEP, an earlier step of this run or of an earlier one
      local spec=${1#file:} path step_
      path=${spec%:*}; step_=${spec##*:}
      [[ -f $path || " ${SELECTED[*]} " == *" $step_ "* ]] || problem "$path is missing: it is made by the step $step_ (bash scripts/results/after_ship.sh --from $step_)" ;;
    "") ;;
    *) echo "after_ship.sh: internal error: unknown prerequisite $1" >&2; exit 1 ;;
  esac
}

# ------------------------------------------------------------------------------------ options

usage() { sed -n '2,/^set -euo/p' "$0" | sed '$d' | sed 's/^# \{0,1\}//'; }
known() { local s; for s in "${STEPS[@]}"; do [[ $s == "$1" ]] && return 0; done; return 1; }
FROM="" TO="" LIST=0
declare -A SKIP=()
while (($#)); do
  case $1 in
    --dry-run) DRY=1 ;;
    --list) LIST=1 ;;
    --from|--to|--skip)
      [[ $# -ge 2 ]] || { echo "after_ship.sh: $1 needs a step name (--list names them)" >&2; exit 2; }
      known "$2" || { echo "after_ship.sh: $1: no step '$2' (--list names them)" >&2; exit 2; }
      case $1 in --from) FROM=$2 ;; --to) TO=$2 ;; *) SKIP[$2]=1 ;; esac
      shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "after_ship.sh: unknown option '$1' (use --dry-run, --list, --from STEP, --to STEP, --skip STEP)" >&2; exit 2 ;;
  esac
  shift
done

if [[ $LIST == 1 ]]; then
  for s in "${STEPS[@]}"; do printf '%-30s %s\n' "$s" "${DOC[$s]}"; done
  exit 0
fi

SELECTED=()
started=$([[ -z $FROM ]] && echo 1 || echo 0)
for s in "${STEPS[@]}"; do
  [[ $s == "$FROM" ]] && started=1
  [[ $started == 1 && -z ${SKIP[$s]:-} ]] && SELECTED+=("$s")
  if [[ $s == "$TO" ]]; then
    [[ $started == 1 ]] || { echo "after_ship.sh: --to $TO comes before --from $FROM (--list gives the order)" >&2; exit 2; }
    break
  fi
done

for s in "${SELECTED[@]}"; do
  for need in ${NEEDS[$s]}; do check "$need"; done
done
if ((${#PROBLEMS[@]})); then
  if [[ $DRY == 1 ]]; then
    printf '# prerequisite missing (a real run stops here, exit 2): %s\n' "${PROBLEMS[@]}"
  else
    echo "after_ship.sh: prerequisites missing, nothing was run:" >&2
    printf '  %s\n' "${PROBLEMS[@]}" >&2
    exit 2
  fi
fi

# ---------------------------------------------------------------------------------------- run

if [[ $DRY == 1 ]]; then
  for s in "${SELECTED[@]}"; do echo "# $s: ${DOC[$s]}"; "step_$s"; done
  exit 0
fi
mkdir -p "$WORK/logs" "$WORK/control"
for s in "${SELECTED[@]}"; do
  echo "== $(date -u '+%F %T UTC') $s: ${DOC[$s]}"
  set +e
  ( set -e; "step_$s" ) 2>&1 | tee "$WORK/logs/$s.log"
  rc=${PIPESTATUS[0]}
  set -e
  if [[ $rc != 0 ]]; then
    echo "after_ship.sh: step $s failed (exit $rc; log $WORK/logs/$s.log); resume with: bash scripts/results/after_ship.sh --from $s" >&2
    exit "$rc"
  fi
done
echo "== $(date -u '+%F %T UTC') done: ${#SELECTED[@]} steps. Now read the docs' prose against the new numbers (the header of scripts/results/after_ship.sh lists where)."
