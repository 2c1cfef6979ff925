"""`stablemo footskate FILE --out FILE`: remove foot skating from a motion file (joints or features; stablemo.skating)."""

from __future__ import annotations

from stablemo.errors import StableMoError
from stablemo.skating.cleanup import StableMoCodec


def main(argv: list[str]) -> int:
    """`stablemo footskate IN.npy --out OUT.npy [--weights PATH] [--iters N]` (joints or features)."""
    from footskate.command import main as footskate_main
    from footskate.errors import FootskateError

    try:
        return footskate_main(argv, codec_factory=StableMoCodec)
    except FootskateError as err:
        raise StableMoError(str(err)) from None
