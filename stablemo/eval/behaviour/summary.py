"""Pass rates of a behaviour run with Wilson 95 % intervals: per attribute, per split, per length,
overall; and the text table the command prints.

A motion passes when every attribute its prompt tests passes. The intervals treat motions as
independent trials; the seeds of one prompt are not fully independent (a model that cannot do a
prompt fails all of them), so read them as a lower bound on the uncertainty.
"""

from __future__ import annotations

import math

from stablemo.eval.behaviour.table import ATTRIBUTES, SPLITS

Z95 = 1.959964


def wilson(passed: int, total: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion; (nan, nan) for no trials."""
    if total <= 0:
        return math.nan, math.nan
    p = passed / total
    centre = (p + z * z / (2 * total)) / (1 + z * z / total)
    half = z * math.sqrt(p * (1 - p) / total + z * z / (4 * total * total)) / (1 + z * z / total)
    return max(0.0, centre - half), min(1.0, centre + half)


def rate(passed: int, total: int) -> dict:
    if total == 0:  # nothing to count (no motion failed): no rate, rather than NaN in the JSON
        return {"passed": 0, "total": 0, "rate": None, "low": None, "high": None}
    lo, hi = wilson(passed, total)
    return {"passed": passed, "total": total, "rate": passed / total if total else math.nan, "low": lo, "high": hi}


def summarize(rows: list[dict]) -> dict:
    """rows: one per motion, {split, length, passed, attributes: {name: {passed, measured}}, r3 (optional)}.
    -> {overall, checks, attributes: {name: rate}, r3, r3_failed (with retrieval), splits: {split: the
    same}, lengths: {length: the same}}"""

    def block(selected: list[dict]) -> dict:
        attrs = {}
        for name in ATTRIBUTES:
            results = [r["attributes"][name]["passed"] for r in selected if name in r["attributes"]]
            if results:
                attrs[name] = rate(sum(results), len(results))
        checks = [v["passed"] for r in selected for v in r["attributes"].values()]
        out = {"overall": rate(sum(r["passed"] for r in selected), len(selected)),
               "checks": rate(sum(checks), len(checks)), "attributes": attrs}
        scored = [r for r in selected if r.get("r3") is not None]
        if scored:  # retrieval of the same motions, and of those that fail a check
            failed = [r["r3"] for r in scored if not r["passed"]]
            out["r3"] = rate(sum(r["r3"] for r in scored), len(scored))
            out["r3_failed"] = rate(sum(failed), len(failed))
        return out

    out = block(rows)
    out["splits"] = {s: block([r for r in rows if r["split"] == s]) for s in SPLITS if any(r["split"] == s for r in rows)}
    lengths = list(dict.fromkeys(r["length"] for r in rows))
    out["lengths"] = {n: block([r for r in rows if r["length"] == n]) for n in lengths}
    return out


def cell(rate: dict | None) -> str:
    """`93.1 [90.2, 95.2]`: percent passed and its Wilson 95 % interval."""
    if not rate or not rate.get("total"):
        return "–"
    return f"{100 * rate['rate']:.1f} [{100 * rate['low']:.1f}, {100 * rate['high']:.1f}]"


def format_table(summary: dict) -> str:
    """Rows: every attribute, then all checks and whole motions; columns: checks counted, then
    percent passed [interval] over all, each split, each length."""
    columns = [("all", summary)] + [(s, b) for s, b in summary["splits"].items()] + \
              [(f"length {n}", b) for n, b in summary["lengths"].items()]
    names = [a for a in ATTRIBUTES if a in summary["attributes"]]
    picks = [(a, lambda b, a=a: b["attributes"].get(a)) for a in names]
    picks += [("all checks", lambda b: b["checks"]), ("motions (every check)", lambda b: b["overall"])]
    if "r3" in summary:
        picks += [("R@3 of the motions", lambda b: b.get("r3")),
                  ("R@3 of those failing a check", lambda b: b.get("r3_failed"))]
    rows = [[name, str((pick(summary) or {}).get("total", "–"))] + [cell(pick(b)) for _, b in columns] for name, pick in picks]
    header = ["% passed [95 % interval]", "n"] + [c for c, _ in columns]
    widths = [max(len(str(r[i])) for r in rows + [header]) for i in range(len(header))]
    line = lambda r: "  ".join(str(v).ljust(w) for v, w in zip(r, widths)).rstrip()
    return "\n".join([line(header), line(["-" * w for w in widths])] + [line(r) for r in rows])


__all__ = ["cell", "format_table", "rate", "summarize", "wilson"]
