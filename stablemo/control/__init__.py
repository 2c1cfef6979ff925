"""Editing and joint control at sampling time, with the trained models as they are.

- `Inpaint` (spec.py): known features kept exactly (in-betweening, prefix/suffix, body parts),
  imposed inside every sampler (stablemo.diffusion.inpainting).
- `JointControl` (spec.py): global joint targets at any joint and frame, reached by guidance on
  the predicted x0 (guidance.py).
- `Turn` (turn.py): the body turns by an asked angle over chosen frames (the root's turn scaled at
  every sampler step); read from a prompt's words for planned requests (stablemo.text.turns).
- parts.py: named feature groups (lower/upper body, root, joints, frames) -> masks; files.py:
  control files (.npz) and writing one from joints.

Both go into a request: `Pipeline.generate(texts, lengths, inpaint=[...], control=[...])`.
"""

from stablemo.control.spec import Inpaint, JointControl
from stablemo.control.turn import Turn

__all__ = ["Inpaint", "JointControl", "Turn"]
