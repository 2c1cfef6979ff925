"""A timeline: contiguous segments `start_s end_s text`, checked, and placed on the frame grid.

    0   5   a person walks forward
    5   10  a person jumps in place
    10  15  a person turns left        # '#' starts a comment; blank lines are skipped

Seconds are decimal numbers; the first segment starts at 0, each next one where the previous ended
(an overlap or a gap is an error naming the line). This is the one timeline format of the CLI
(`--timeline FILE`), the API (/api/stream's `timeline`) and the page; the page also takes the
shorthand `<seconds> <prompt>` (each line starting where the previous one ended), which it shows
back in this format (`canonical_timeline`). Segment boundaries are rounded to frames once,
from the absolute times (not from the durations), so the total length is exactly
round(last end x fps) frames whatever the number of segments.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from stablemo.errors import StableMoError
from stablemo.motion.plausible import MAX_TIMELINE_SECONDS

# Two times closer than this are the same instant: "0 2.5" then "2.5 5" must not be a 1e-16 s gap
# after float parsing; a millisecond is far below a frame at any frame rate a model uses.
_SAME_INSTANT_S = 1e-3


@dataclass(frozen=True)
class Segment:
    """One prompt of a timeline: [start_s, end_s) seconds and its text."""

    start_s: float
    end_s: float
    text: str


def check_segments(segments: Sequence[Segment | tuple], source: str = "segments",
                   lines: Sequence[int] | None = None) -> list[Segment]:
    """Segments as `Segment`s, contiguous from 0; one clear error naming the entry (or file line)."""
    out: list[Segment] = []
    if not segments:
        raise StableMoError(f"{source}: the timeline has no segments")
    for i, seg in enumerate(segments):
        where = f"{source}:{lines[i]}" if lines else f"{source}[{i}]"
        if not isinstance(seg, Segment):
            try:
                start, end, text = seg
            except (TypeError, ValueError):
                raise StableMoError(f"{where}: expected (start_s, end_s, text), got {seg!r}") from None
            seg = Segment(start, end, text)
        for name in ("start_s", "end_s"):
            value = getattr(seg, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise StableMoError(f"{where}: {name} must be a finite number of seconds, got {value!r}")
        if not isinstance(seg.text, str) or not seg.text.strip():
            raise StableMoError(f"{where}: empty prompt")
        if seg.end_s > MAX_TIMELINE_SECONDS:
            raise StableMoError(f"{where}: ends at {seg.end_s:g} s; a timeline is at most {MAX_TIMELINE_SECONDS:g} s "
                                "(split a longer show into several timelines)")
        if seg.end_s <= seg.start_s:
            raise StableMoError(f"{where}: ends at {seg.end_s:g} s, not after its start {seg.start_s:g} s")
        expected = out[-1].end_s if out else 0.0
        if abs(seg.start_s - expected) > _SAME_INSTANT_S:
            if not out:
                problem = f"starts at {seg.start_s:g} s; the first segment must start at 0"
            elif seg.start_s < expected:
                problem = f"starts at {seg.start_s:g} s, overlapping the previous segment (which ends at {expected:g} s)"
            else:
                problem = f"starts at {seg.start_s:g} s, leaving a gap after the previous segment (which ends at {expected:g} s)"
            raise StableMoError(f"{where}: {problem}; segments must be contiguous")
        out.append(Segment(float(expected), float(seg.end_s), seg.text.strip()))
    return out


def _number(word: str) -> float | None:
    try:
        value = float(word)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _rows(text: str, source: str, shorthand: bool) -> list[tuple[int, float, float, str, bool]]:
    """(line number, start, end, prompt, written as shorthand) of each timeline line. Two leading
    numbers are always start and end, so `5 10 a person jumps` is never the prompt "10 a person
    jumps"; with `shorthand`, a line with one leading number is `<seconds> <prompt>`, starting where
    the line before it ended."""
    rows: list[tuple[int, float, float, str, bool]] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split(None, 2)
        first = _number(parts[0])
        second = _number(parts[1]) if len(parts) > 1 else None
        if shorthand and first is not None and second is None and len(parts) >= 2:
            start = rows[-1][2] if rows else 0.0
            if first <= 0:
                raise StableMoError(f"{source}:{number}: a line '<seconds> <prompt>' needs seconds > 0, got {parts[0]!r}")
            rows.append((number, start, start + first, line.split(None, 1)[1], True))
            continue
        if len(parts) < 3:
            raise StableMoError(f"{source}:{number}: expected 'start_s end_s text', got {raw.strip()!r}")
        if first is None:
            raise StableMoError(f"{source}:{number}: start time {parts[0]!r} is not a number of seconds")
        if second is None:
            raise StableMoError(f"{source}:{number}: end time {parts[1]!r} is not a number of seconds (lines are "
                                "'start_s end_s text'; '<seconds> <prompt>' is only the page's shorthand)")
        rows.append((number, first, second, parts[2], False))
    if not rows:
        raise StableMoError(f"{source}: no segments (lines 'start_s end_s text')")
    return rows


def parse_timeline(text: str, source: str = "timeline", shorthand: bool = False) -> list[Segment]:
    """Timeline text (lines `start_s end_s text`) -> checked segments; errors name `source:line`.
    shorthand: also read `<seconds> <prompt>` lines (the page's), each starting where the previous
    line ended; `canonical_timeline` writes such a text back in the one format."""
    rows = _rows(text, source, shorthand)
    return check_segments([r[1:4] for r in rows], source, [r[0] for r in rows])


def _seconds(value: float) -> str:
    return f"{round(value, 3):g}"


def canonical_timeline(text: str, source: str = "timeline") -> str:
    """The text with every `<seconds> <prompt>` line rewritten as `start_s end_s prompt`, its comment
    kept; every other line (comments, blank lines, lines already in the format) as it was. Checked
    as parse_timeline(text, shorthand=True) checks it."""
    parse_timeline(text, source, shorthand=True)
    rows = {r[0]: r for r in _rows(text, source, shorthand=True) if r[4]}
    out = []
    for number, raw in enumerate(text.splitlines(), start=1):
        if number in rows:
            _, start, end, prompt, _ = rows[number]
            comment = raw.partition("#")[1] + raw.partition("#")[2]
            raw = f"{_seconds(start)} {_seconds(end)} {prompt}" + (f"  {comment}" if comment else "")
        out.append(raw)
    return "\n".join(out) + "\n"


def format_timeline(segments: Sequence[Segment]) -> str:
    """Segments as timeline text, one `start_s end_s text` line each (parse_timeline reads it back)."""
    return "".join(f"{_seconds(s.start_s)} {_seconds(s.end_s)} {s.text}\n" for s in segments)


def read_timeline(path: str | Path) -> list[Segment]:
    """A timeline file -> checked segments (UTF-8; errors name the file and line)."""
    from stablemo.io import read_text

    return parse_timeline(read_text(path, "timeline file"), str(path))


def segment_frames(segments: Sequence[Segment], fps: float, source: str = "segments") -> list[tuple[int, int]]:
    """[start, end) frames of each segment, rounded from the absolute times (exact total length);
    a segment that rounds to no frame is an error naming it."""
    bounds = [0] + [round(seg.end_s * fps) for seg in segments]
    out = []
    for i, (a, b) in enumerate(itertools.pairwise(bounds)):
        if b <= a:
            raise StableMoError(f"{source}[{i}] ({segments[i].text!r}): {segments[i].end_s - segments[i].start_s:g} s "
                                f"is shorter than one frame at {fps:g} fps")
        out.append((a, b))
    return out


__all__ = ["Segment", "canonical_timeline", "check_segments", "format_timeline", "parse_timeline", "read_timeline",
           "segment_frames"]
