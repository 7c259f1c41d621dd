"""The pixels of an overhead frame that stand above the table, with their world points.

Why a type of its own: the robot's finger checks, size cue, clearance height maps and
relocation read world points only where something stands on the table (about a tenth of an
overhead frame), yet transforming the whole frame to the world was ~4 ms of the robot's ~0.2 s
per scene (``benchmarks/bench_perception.py``). Here the mask comes from every pixel's world
height alone (one matrix-vector product, ``Observation.world_z``) and the world points from the
raised pixels' camera points (``Observation.points_world_at``); both equal the matching entries of
``Observation.points_world()`` bit for bit (``tests/test_raised_points.py``), so every consumer
reads the same numbers as before, in the same row-major order as ``world[pixels & mask]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..perception.observation import Observation
from ..perception.roi import BoolMask

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class RaisedPoints:
    """``mask``: ``[H, W]`` pixels whose world point lies more than a tolerance above the table
    (no depth: not); ``pixels``: their flat indices, ascending; ``points``: their world points
    ``[n, 3]``, in that order."""

    mask: BoolMask
    pixels: npt.NDArray[np.intp]
    points: FloatArray

    @classmethod
    def of(cls, obs: Observation, table_z: float, tolerance: float) -> RaisedPoints:
        """The raised pixels of ``obs`` (``perceive.raised_mask``'s, from the heights alone)."""
        if not tolerance >= 0:  # a pixel without depth must not count as raised (raised_mask's NaN rule)
            raise ValueError(f"tolerance must be >= 0 m, got {tolerance}")
        mask: BoolMask = obs.world_z() > table_z + tolerance  # NaN compares False: no depth, not raised
        pixels = np.flatnonzero(mask)
        return cls(mask, pixels, obs.points_world_at(pixels))

    def within(self, pixels: BoolMask) -> FloatArray:
        """World points of ``pixels & mask``, row-major: ``points_world()[pixels & mask]``."""
        out: FloatArray = self.points[pixels.ravel()[self.pixels]]
        return out

    def outside(self, pixels: BoolMask) -> FloatArray:
        """World points of ``~pixels & mask``, row-major: every raised surface but ``pixels``'."""
        out: FloatArray = self.points[~pixels.ravel()[self.pixels]]
        return out


def object_centre(raised: RaisedPoints, mask: BoolMask) -> tuple[float, float] | None:
    """The centre on the table of the object under ``mask``: the mean x, y of its raised world
    points (None without any). What the release aims at the drop zone (``episode.release_spots``):
    the robot's own view before it moves, not the simulator's pose of the body."""
    points = raised.within(mask)
    if not len(points):
        return None
    return float(points[:, 0].mean()), float(points[:, 1].mean())


#: At most this many of an object's seen points stand for it in the carry check
#: (``episode._carry_hit``): every n-th, row-major, so a large object costs no more than a small.
HELD_POINTS = 256


def object_points(raised: RaisedPoints, mask: BoolMask, limit: int = HELD_POINTS) -> FloatArray | None:
    """The seen surface of the object under ``mask``: at most ``limit`` of its raised world
    points ``[n, 3]``, evenly strided (None without any). What the carry keeps clear of the arm
    once the object is in the hand (``episode.execute_pick``)."""
    if limit < 1:
        raise ValueError(f"limit must be >= 1, got {limit}")
    points = raised.within(mask)
    if not len(points):
        return None
    out: FloatArray = points[:: max(1, math.ceil(len(points) / limit))]
    return out
