"""Procedural motion-language dataset on the HumanML3D skeleton (the offline default).

`write_dataset(out_dir, num, seed)` writes it in the HumanML3D layout; `generate_motion(rng)`
makes one motion (joints, contacts, captions). See docs/synth.md.
"""

from stablemo.data.synth.actions import ACTIONS
from stablemo.data.synth.compose import SynthMotion, generate_motion
from stablemo.data.synth.writer import write_dataset

__all__ = ["ACTIONS", "SynthMotion", "generate_motion", "write_dataset"]
