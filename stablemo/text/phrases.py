"""Words and phrases of a YAML word list as one regular-expression alternative, for the readers of
what a prompt says (stablemo.text.plan: its order; stablemo.text.turns: how far it turns)."""

from __future__ import annotations

import re


def alternatives(phrases, gap: str = r"\s+") -> str:
    """A regex alternative of the phrases, longest first (so "after that" wins over "after"), each
    matched literally with `gap` between its words (default any whitespace)."""
    return "|".join(gap.join(map(re.escape, p.split())) for p in sorted(phrases, key=len, reverse=True))


__all__ = ["alternatives"]
