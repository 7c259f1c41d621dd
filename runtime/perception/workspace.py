"""The part of a camera's view the robot picks from: a box on the table, or a mask of pixels.

Why: a camera that is not straight above the table, or farther from it than the testbed's, sees
more than the objects: the robot's own base and arm, the table's edge, the floor. Segmentation
finds everything that stands above the table plane, so those become regions like any object, and
grounding may choose one. On sim-dev scenes seen from 45 degrees on the far side of the table, the
arm was chosen (as a "pitcher", to pour, contain or drink with) in 6 of 35 scenes
(``benchmarks/bench_frame_views.py``).
A real robot knows where its workspace is; this is how it says so:

* ``Workspace``: an x-y box in the camera pose's world frame (metres, z up), and optionally a
  ceiling ``z_max`` in the same frame, above which nothing is an object to pick (the arm's links
  hanging over the table). A pixel whose depth point lies outside it is no part of any region.
  It needs the camera's pose: without one the frame's axes are arbitrary.
* a mask: pixels to perceive (True) and to ignore (False), in the image; for a robot that
  filters its own body from the image, or a camera whose pose is not known.

Only segmentation reads them (``frame.frame_keep``, ``segment``'s ``keep``): the table is fitted,
and the grasp network, the finger checks and the hand's approach see, the whole frame, so the
robot's base beside an object is still an obstacle to the hand. An object reaching out of the box
keeps only its part inside.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

#: metres: no robot's workspace reaches farther from its world's origin (as ``frame.MAX_POSE_M``)
MAX_WORKSPACE_M = 1e6


@dataclass(frozen=True)
class Workspace:
    """An axis-aligned box on the table, in the world frame of the camera's pose (metres); with
    ``z_max``, points higher than it (world z, not height above the table) are outside too."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    z_max: float | None = None

    def __post_init__(self) -> None:
        values = (self.x_min, self.x_max, self.y_min, self.y_max, *(() if self.z_max is None else (self.z_max,)))
        if not all(math.isfinite(v) and abs(v) <= MAX_WORKSPACE_M for v in values):
            raise ValueError(f"a workspace's bounds are finite metres within {MAX_WORKSPACE_M:g}, got "
                             f"{', '.join(f'{v:g}' for v in values)}")
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ValueError(f"a workspace is x_min,x_max,y_min,y_max with each minimum below its maximum, got "
                             f"{', '.join(f'{v:g}' for v in values)}")

    @classmethod
    def parse(cls, text: str) -> Workspace:
        """``"x_min,x_max,y_min,y_max[,z_max]"`` (metres); ``ValueError`` saying what is wrong."""
        usage = "x_min,x_max,y_min,y_max in metres, and optionally z_max (e.g. 0.14,0.61,-0.30,0.30,0.30)"
        parts = [p.strip() for p in text.split(",")]
        if len(parts) not in (4, 5):
            raise ValueError(f"{text!r}: a workspace is four or five numbers, {usage}")
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise ValueError(f"{text!r}: a workspace is four or five numbers, {usage}") from None
        return cls(*values)

    def bounds(self) -> list[float]:
        """x_min, x_max, y_min, y_max and z_max when set, as ``parse`` reads them (for JSON)."""
        return [self.x_min, self.x_max, self.y_min, self.y_max, *(() if self.z_max is None else (self.z_max,))]

    def contains(self, points: npt.NDArray[np.floating]) -> npt.NDArray[np.bool_]:
        """Which points ``[..., 3]`` lie inside (by x and y, and z under ``z_max`` when set); NaN
        points do not."""
        x, y = points[..., 0], points[..., 1]
        with np.errstate(invalid="ignore"):
            inside: npt.NDArray[np.bool_] = (x >= self.x_min) & (x <= self.x_max) & (y >= self.y_min) & (y <= self.y_max)
            if self.z_max is not None:
                inside &= points[..., 2] <= self.z_max
        return inside


def mask_from_image(image: npt.NDArray[np.generic]) -> npt.NDArray[np.bool_]:
    """A mask image's pixels to perceive: non-zero in any channel (white, or any colour, on black).
    ``ValueError`` for an image that is not H x W or H x W x C."""
    if image.ndim == 3:
        return np.asarray(np.any(image != 0, axis=2))
    if image.ndim == 2:
        return np.asarray(image != 0)
    raise ValueError(f"a mask is an H x W image, got shape {image.shape}")
