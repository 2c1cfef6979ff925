"""How far a written file's joints are from the motion it was written from, and the warning past 3 cm.

One measure for every writer (BVH, the SMPL .npz: both pose the same rig) and every place a file is
made: `stablemo bvh` and `stablemo generate --format bvh` print the warning on stderr, the server
returns it in a `warnings` list, the page shows it beside the BVH button, and the Python API hands
the `Fit` back (`export_motion(...).fit`, `write_bvh(...)`) without printing anything.

The file's joints are its forward kinematics at the motion's own frame rate (before any
resampling), in metres, against the motion's joints in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WARN_M = 0.03  # a joint further than this from the motion is visible in a viewer: say so


@dataclass(frozen=True)
class Fit:
    """The file's joints against the motion's: mean and max distance (metres) over every joint and
    frame, and where the max is."""

    mean_m: float
    max_m: float
    frame: int
    joint: str

    @property
    def close(self) -> bool:
        return self.max_m <= WARN_M

    def summary(self) -> str:
        return f"joints within {self.mean_m * 100:.2f} cm on average, {self.max_m * 100:.2f} cm at most"

    def warning(self, name: str, hint: str = "") -> str | None:
        """One line naming the file when a joint is more than WARN_M off, else None.
        hint: what the caller can do about it (e.g. the option that follows the motion)."""
        if self.close:
            return None
        return (f"warning: {name} is up to {self.max_m * 100:.1f} cm from the motion ({self.joint} at frame "
                f"{self.frame}; {self.mean_m * 100:.1f} cm on average): the file's body is rigid and the motion's "
                f"is not (bones that change length, or hips and shoulders that move against the spine)"
                f"{'; ' + hint if hint else ''}")


def measure_fit(file_joints_m: np.ndarray, joints_m: np.ndarray, names) -> Fit:
    """file_joints_m, joints_m: (T, J, 3) metres, the same joints in the same order; names: J joint names."""
    err = np.linalg.norm(np.asarray(file_joints_m) - np.asarray(joints_m), axis=-1)  # (T, J)
    frame, joint = np.unravel_index(int(np.argmax(err)), err.shape)
    return Fit(float(err.mean()), float(err.max()), int(frame), str(names[joint]))
