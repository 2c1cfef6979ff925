"""Long and streaming motion: a timeline of prompts as one motion of any length (compose), the same
timeline streamed by whole prompts (timeline_stream), and chunked streaming conditioned on what was
produced, its text free to change between chunks (stream). docs/long_motion.md."""

from stablemo.timeline.compose import TimelineMotion, generate_timeline
from stablemo.timeline.spec import (
           Segment,
           canonical_timeline,
           check_segments,
           format_timeline,
           parse_timeline,
           read_timeline,
           segment_frames,
)
from stablemo.timeline.stream import Chunk, stream
from stablemo.timeline.timeline_stream import TimelineStream, stream_timeline
from stablemo.timeline.windows import Window, plan_windows

__all__ = ["Chunk", "Segment", "TimelineMotion", "TimelineStream", "Window", "canonical_timeline", "check_segments",
           "format_timeline", "generate_timeline", "parse_timeline", "plan_windows", "read_timeline", "segment_frames",
           "stream", "stream_timeline"]
