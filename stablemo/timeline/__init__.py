"""Long and streaming motion: a timeline of prompts as one motion of any length (compose), and
chunked streaming conditioned on what was produced (stream). docs/long_motion.md."""

from stablemo.timeline.compose import (
           TimelineMotion,
           Window,
           generate_timeline,
           plan_windows,
)
from stablemo.timeline.spec import (
           Segment,
           check_segments,
           parse_timeline,
           read_timeline,
           segment_frames,
)
from stablemo.timeline.stream import Chunk, stream

__all__ = ["Chunk", "Segment", "TimelineMotion", "Window", "check_segments", "generate_timeline", "parse_timeline",
           "plan_windows", "read_timeline", "segment_frames", "stream"]
