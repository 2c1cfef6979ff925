"""docs/results.md's behaviour section and its picture, from the runs kept in docs/data/results/.

    stablemo behaviour --bundle stablemo/assets/demo_bundle  --out docs/data/results/behaviour_teacher.json
    stablemo behaviour --bundle stablemo/assets/demo_student --out docs/data/results/behaviour_student.json
    stablemo behaviour --bundle stablemo/assets/demo_bundle  --whole --out docs/data/results/behaviour_teacher_whole.json
    stablemo behaviour --bundle stablemo/assets/demo_student --whole --out docs/data/results/behaviour_student_whole.json
    stablemo behaviour --ground-truth                        --out docs/data/results/behaviour_ground_truth.json
    python scripts/results/behaviour_report.py [--results docs/results.md]

Draws docs/data/results/behaviour.png (pass rate per attribute per model) and puts the section
(stablemo.eval.behaviour.report) into the results file in place of the one there, before the
joint-control sections; scripts/results/make_results.py renders the same section when it rewrites
the whole file.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from stablemo.errors import StableMoError
from stablemo.eval.behaviour.report import (
    FILES,
    PICTURE,
    chart,
    load,
    results_section,
    write_section,
)

DOCS = Path(__file__).resolve().parents[2] / "docs"


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default=str(DOCS / "data" / "results"), help="folder of the behaviour_*.json runs")
    p.add_argument("--results", default=str(DOCS / "results.md"), help="the results file to update")
    args = p.parse_args(argv)
    folder = Path(args.data)
    runs = {label: load(folder / name) for label, name in FILES.items() if (folder / name).is_file()}
    if not runs:
        raise StableMoError(f"--data: {folder} holds none of {', '.join(FILES.values())}")
    chart(runs, folder / PICTURE)
    write_section(args.results, results_section(folder))
    print(f"wrote {folder / PICTURE} and the behaviour section of {args.results} ({', '.join(runs)})")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv[1:]))
    except StableMoError as err:
        print(f"{Path(sys.argv[0]).name}: error: {err}", file=sys.stderr)
        sys.exit(2)
