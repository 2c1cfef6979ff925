"""The behaviour section of docs/results.md and its picture, from the JSON that `stablemo behaviour
--out` writes (docs/data/results/behaviour_<model>.json).

`dumps` writes such a file and `load` reads it back; `section(results)` renders the section (per-attribute pass rates with Wilson intervals for every
model, suite against held-out, per length); `write_section(path, text)` puts it into the results
file in place of an older one (before the joint-control sections, where
scripts/results/make_results.py renders it too); `chart(results, path)` draws the bar chart.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from stablemo.errors import StableMoError
from stablemo.eval.behaviour.summary import cell
from stablemo.eval.behaviour.table import ATTRIBUTES, SPLITS

TITLE = "## Behaviour: does the motion do what the prompt says"
NEXT_SECTIONS = ("\n## Joint control by guidance", "\n## Provenance")  # the section goes before the first found
INTRO = f"""
{TITLE}

R-precision asks whether a motion lies nearer its own text than 31 others in the evaluator's space:
a motion can be "near" a prompt for jumping twice while jumping four times, wave the wrong hand, turn
270 degrees for "a quarter turn", or do the two parts of "X, then Y" the other way round. The
behaviour suite (`stablemo behaviour`, docs/evaluation.md "Behaviour") generates each of its prompts
at several lengths and seeds and checks from the joints what the text asks: counts of flights, hops,
squats, punches and claps; which hand or foot; the direction of travel against the facing; the turn
angle; the cruising speed; the body part doing the action; which part of a composite comes first.
The column "ground truth" scores the synthetic generator's own motions of the same prompts, lengths
and seeds (`stablemo behaviour --ground-truth`): the checks' validation; tests/test_behaviour.py also
shows each check failing on motions wrong in its attribute (mirrored bodies, one jump more, the parts
reversed, another speed, angle or limb). `suite` prompts are sentences the training captions
can produce; `held_out` ones use a paraphrase or a subject none of them uses. Lengths: `default` (no
length given: the bundle's length predictor chooses it, stablemo.text.length; for the ground truth
6 s), `natural` (the length the synthetic generator gives the actions, 2-9 s), seconds (`6`, the
fixed default before the length predictor; `9.8`, longer than any action needs). The columns
"whole" give the network each prompt whole at each length (`stablemo behaviour --whole`); the others
score what `stablemo generate` gives: a prompt that says an order made part by part, a length
longer than the text asks for ending standing (docs/inference.md, "Prompts in parts"), and a turn
whose angle the text says turned by that angle (docs/inference.md, "Turns as said"; the angle check
then measures the network's steps and the reading of the words, not the network's sense of an
angle: the columns "whole" keep that). (The demo
models before their input head and temporal attention, docs/training.md, passed 35.8 % (teacher) and
37.7 % (student) of motions whole; their runs are in git history.) Percent passed
[Wilson 95 % interval]; the intervals treat motions as independent, which the 4 seeds of one prompt
are not quite.

What R@3 misses: it asks whether a motion is nearer its own text than 31 others, which are mostly
other actions, so a motion of the right kind with the wrong count, side, angle or order still ranks
its text in the top 3. Each run below also takes the R@3 of its very motions (the packaged synthetic
evaluator, batches of 32 distinct prompts; rows "R@3"), over all motions and over the motions that
fail a check.

"""


# docs/data/results/: the runs the docs show (label -> file), and the picture drawn from them. The
# shipped models twice: given each prompt whole (`stablemo behaviour --whole`, the network alone) and
# as `stablemo generate` gives them (prompts in parts, stablemo.timeline.planned)
FILES = {"ground truth": "behaviour_ground_truth.json",
         "teacher, whole": "behaviour_teacher_whole.json", "1-step student, whole": "behaviour_student_whole.json",
         "teacher": "behaviour_teacher.json", "1-step student": "behaviour_student.json"}
PICTURE = "behaviour.png"


def dumps(settings: dict, result: dict) -> str:
    """The results file of a run_suite result: settings, summary and the prompts indented, then one
    line per motion (diffs stay readable)."""
    head = json.dumps({"settings": settings, "summary": result["summary"], "prompts": result["prompts"]}, indent=1)
    rows = result["rows"]
    lines = ",\n".join("  " + json.dumps(r, separators=(", ", ": ")) for r in rows)
    return head[:-2] + ',\n "rows": [\n' + lines + "\n ]\n}\n"


def load(path: str | Path) -> dict:
    """A results file written by `stablemo behaviour --out`; one line naming it if it is not one."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise StableMoError(f"{path}: not a behaviour results file ({err})") from None
    if not isinstance(data, dict) or not {"settings", "summary", "prompts", "rows"} <= set(data):
        raise StableMoError(f"{path}: not a behaviour results file (no settings, summary, prompts and rows)")
    return data


def _model_name(result: dict) -> str:
    return result["settings"].get("label") or Path(str(result["settings"].get("model", "?"))).name


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows]) + "\n"


def _attribute_rows(blocks: list[dict], counted: list[dict]) -> list[list[str]]:
    """Rows per attribute, then all checks and whole motions: the number of checks in each block of
    `counted`, then the pass rate [interval] in each block of `blocks`."""
    picks = [(a, lambda b, a=a: b["attributes"].get(a)) for a in ATTRIBUTES if any(a in b["attributes"] for b in blocks)]
    picks += [("all checks", lambda b: b["checks"]), ("motions (every check)", lambda b: b["overall"])]
    rows = [[name] + [str((pick(c) or {}).get("total", "–")) for c in counted] + [cell(pick(b)) for b in blocks]
            for name, pick in picks]
    if any("r3" in b for b in blocks):
        rows.append(["R@3 of the motions"] + [str((c.get("r3") or {}).get("total", "–")) for c in counted]
                    + [cell(b.get("r3")) for b in blocks])
        # the motions failing a check differ from model to model: each cell says how many
        rows.append(["R@3 of those failing a check"] + ["per model"] * len(counted)
                    + [f"{cell(b.get('r3_failed'))} of {(b.get('r3_failed') or {}).get('total', 0)}" for b in blocks])
    return rows


def _per_action(result: dict) -> dict[str, dict]:
    """{action or "composite of n": rate of motions passing every check}, in the table's order."""
    from stablemo.eval.behaviour.summary import rate

    groups: dict[str, list[bool]] = {}
    for row in result["rows"]:
        actions = result["prompts"][row["prompt"]]["actions"]
        key = actions[0] if len(actions) == 1 else f"composite of {len(actions)}"
        groups.setdefault(key, []).append(row["passed"])
    return {k: rate(sum(v), len(v)) for k, v in groups.items()}


def section(results: dict[str, dict], picture: str | None = None) -> str:
    """The markdown section for {label: result JSON}."""
    names = list(results)
    summaries = [results[n]["summary"] for n in names]
    out = [INTRO]
    settings = [results[n]["settings"] for n in names]
    for name, s in zip(names, settings):
        secs = s.get("seconds", {})
        if "sampler" not in s:  # the synthetic motions
            out.append(f"- {name}: {s.get('model')}, {s.get('prompts')} prompts x {len(s.get('lengths', []))} lengths "
                       f"x {len(s.get('seeds', []))} seeds; {secs.get('total', '?')} s, measured {s.get('started')}.\n")
            continue
        out.append(f"- {name}: `{s.get('model')}`, {s.get('sampler')} {s.get('steps')} step(s), cfg {s.get('cfg')}, "
                   f"{s.get('prompts')} prompts x {len(s.get('lengths', []))} lengths x {len(s.get('seeds', []))} seeds, "
                   f"{s.get('device')}; {secs.get('total', '?')} s ({secs.get('generating', '?')} s generating), "
                   f"measured {s.get('started')}. Prompts the bundle calls unfamiliar: {len(s.get('unfamiliar', []))} "
                   f"of {s.get('prompts')}.\n")
    said = [f"{n}: R@3 {100 * sm['r3']['rate']:.1f} % of its motions, {100 * sm['overall']['rate']:.1f} % pass "
            f"every check, and {100 * sm['r3_failed']['rate']:.1f} % of those failing one are R@3 hits"
            for n, sm in zip(names, summaries) if sm.get("r3_failed", {}).get("total")]
    if said:
        out.append("\nOn the same motions, " + "; ".join(said) + ".\n")
    out.append("\nPer attribute, all prompts and lengths:\n\n")
    out.append(_table(["attribute", "checks"] + names, _attribute_rows(summaries, summaries[:1])))
    if picture:
        out.append(f"\n![pass rate per attribute]({picture})\n")
    out.append("\nSuite against held-out prompts (all lengths):\n\n")
    splits = [sp for sp in SPLITS if sp in summaries[0]["splits"]]
    blocks = [summaries[i]["splits"].get(sp, {"attributes": {}, "checks": {}, "overall": {}})
              for i in range(len(names)) for sp in splits]
    out.append(_table(["attribute"] + [f"checks, {sp}" for sp in splits] + [f"{n}, {sp}" for n in names for sp in splits],
                      _attribute_rows(blocks, [summaries[0]["splits"][sp] for sp in splits])))
    out.append("\nPer action (motions passing every check, all lengths; composites by their number of parts):\n\n")
    per_action = [_per_action(results[n]) for n in names]
    keys = list(dict.fromkeys(k for table in per_action for k in table))
    out.append(_table(["prompts of", "motions"] + names,
                      [[k, str(per_action[0].get(k, {}).get("total", "–"))] + [cell(t.get(k)) for t in per_action]
                       for k in keys]))
    out.append("\nPer length (whole motions passing every check; the count, angle and order checks, which a length "
               "unlike the action's own breaks; the R@3 of the same motions):\n\n")
    lengths = list(summaries[0]["lengths"])
    rows = []
    for what, pick in (("motions", lambda b: b["overall"]), ("count", lambda b: b["attributes"].get("count")),
                       ("angle", lambda b: b["attributes"].get("angle")), ("order", lambda b: b["attributes"].get("order")),
                       ("R@3", lambda b: b.get("r3")), ("R@3, failing a check", lambda b: b.get("r3_failed"))):
        if what.startswith("R@3") and not any("r3" in sm for sm in summaries):
            continue
        for i, n in enumerate(names):
            rows.append([what, n] + [cell(pick(summaries[i]["lengths"][ln])) if ln in summaries[i]["lengths"] else "–"
                                     for ln in lengths])
    out.append(_table(["", "model"] + [f"length {ln}" for ln in lengths], rows))
    return "".join(out)


def results_section(folder: str | Path) -> str:
    """The section for the runs of FILES kept in `folder` (docs/data/results), "" when none is."""
    folder = Path(folder)
    results = {label: load(folder / name) for label, name in FILES.items() if (folder / name).is_file()}
    if not results:
        return ""
    picture = f"data/results/{PICTURE}" if (folder / PICTURE).is_file() else None
    return section(results, picture)


def write_section(path: str | Path, text: str) -> None:
    """Replace the behaviour section of the results file at `path` (or insert it before the
    joint-control sections), atomically."""
    from stablemo.io import write_text

    path = Path(path)
    doc = path.read_text(encoding="utf-8")
    start = doc.find("\n" + TITLE)
    if start >= 0:
        end = doc.find("\n## ", start + 1)
        doc = doc[:start] + doc[end if end >= 0 else len(doc):]
    at = next((doc.find(s) for s in NEXT_SECTIONS if doc.find(s) >= 0), -1)
    if at < 0:
        raise StableMoError(f"{path}: found none of the sections the behaviour section goes before")
    write_text(path, doc[:at] + text.rstrip("\n") + "\n" + doc[at:])


def chart(results: dict[str, dict], path: str | Path) -> None:
    """Bars: pass rate per attribute, all checks, whole motions (and the R@3 of the same motions) per
    model, Wilson 95 % intervals as whiskers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stablemo.outputs.render import save_png

    names = list(results)
    attrs = [a for a in ATTRIBUTES if any(a in results[n]["summary"]["attributes"] for n in names)]
    retrieval = all("r3" in results[n]["summary"] for n in names)
    labels = attrs + ["all checks", "motions"] + (["R@3"] if retrieval else [])
    fig, ax = plt.subplots(figsize=(max(11.0, 3.4 * len(names)), 4.4))  # room for each bar's number
    width = 0.8 / len(names)
    x = np.arange(len(labels))
    colours = {"ground truth": "#9e9e9e"}
    for k, n in enumerate(names):
        s = results[n]["summary"]
        rates = [s["attributes"].get(a) for a in attrs] + [s["checks"], s["overall"]] + ([s["r3"]] if retrieval else [])
        mid = np.array([100 * r["rate"] if r else np.nan for r in rates])
        err = np.array([[100 * (r["rate"] - r["low"]), 100 * (r["high"] - r["rate"])] if r else [0, 0]
                        for r in rates]).T.clip(min=0)  # rounding can put a bound a hair past the rate
        bars = ax.bar(x + (k - (len(names) - 1) / 2) * width, mid, width, yerr=err, capsize=2, label=n,
                      color=colours.get(n, f"C{k}"), error_kw={"elinewidth": 0.8})
        for bar, v in zip(bars, mid):
            ax.text(bar.get_x() + bar.get_width() / 2, 1.5, f"{v:.0f}", ha="center", va="bottom", fontsize=7,
                    rotation=90 if len(names) > 3 else 0)
    for level, text, style in ((95, "95 %: target, teacher", "--"), (85, "85 %: every attribute", ":")):
        ax.axhline(level, color="black", lw=0.7, ls=style)
        ax.text(1.005, level, text, transform=ax.get_yaxis_transform(), va="center", fontsize=7)
    ax.set_xticks(x, labels, rotation=20)
    ax.set_xlim(-0.6, len(labels) - 0.4)
    ax.set_ylim(0, 100)
    ax.set_ylabel("% passed (Wilson 95 % interval)")
    ax.set_title("Behaviour suite: does the motion do what the prompt says?", fontsize=10)
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.06), fontsize=8, ncol=len(names), frameon=False)
    fig.tight_layout()
    save_png(fig, path)
    plt.close(fig)


__all__ = ["FILES", "PICTURE", "TITLE", "chart", "dumps", "load", "results_section", "section", "write_section"]
