"""Merge the CSVLogger files of a (possibly resumed) run into one CSV, one row per logged step.

    python scripts/merge_logs.py runs/demo/logs docs/demo_training_log.csv
"""

from __future__ import annotations

import csv
import io
import sys
from pathlib import Path

from stablemo.io import write_text


def merge(log_dir: Path) -> tuple[list[str], list[dict]]:
    rows: dict[int, dict] = {}
    columns: list[str] = []
    for metrics in sorted(log_dir.glob("version_*/metrics.csv"), key=lambda p: int(p.parent.name.split("_")[1])):
        with metrics.open() as f:
            for row in csv.DictReader(f):
                columns += [c for c in row if c not in columns]
                # a resumed run re-logs steps after its checkpoint: the later version wins
                step = rows.setdefault(int(row["step"]), {})
                step.update({k: v for k, v in row.items() if v != ""})
    return columns, [rows[s] for s in sorted(rows)]


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    columns, rows = merge(Path(argv[0]))
    if not rows:
        print(f"{argv[0]}: no metrics.csv found", file=sys.stderr)
        return 1
    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=columns)
    writer.writeheader()
    writer.writerows(rows)
    write_text(argv[1], buffer.getvalue())  # atomic: a failed merge never truncates the old CSV
    print(f"wrote {argv[1]} ({len(rows)} steps)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
