"""An ROI's extents from depth: the three edges of its box in metres, longest first.

The size cue (``grounding/size_cue.py``) compares them with objects' typical sizes. From the
overhead camera the height is the top of the ROI's points above the table, and the footprint the
spread of those points along their two principal axes; percentiles rather than extremes, so a few
stray depth pixels at the mask's edge do not stretch the box. Sorted, so the pose does not matter.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

#: Fewer raised points than this and the ROI is not measured (its size cue is neutral).
MIN_POINTS = 30
TOP_PERCENTILE = 98.0
EDGE_PERCENTILE = 1.0


def measure_extents(points: npt.NDArray[np.floating], table_z: float) -> tuple[float, float, float] | None:
    """``points`` ``[M, 3]`` (world frame, z up; NaN rows ignored) of one object above a table at
    ``table_z``; ``None`` when too few points to measure."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    # a row is finite iff its sum is (metres: no overflow); three vector adds, faster than
    # numpy's sum over an axis of length 3; the robot's raised points are all finite: no copy
    finite = np.isfinite(pts[:, 0] + pts[:, 1] + pts[:, 2])
    if not finite.all():
        pts = pts[finite]
    if len(pts) < MIN_POINTS:
        return None
    xy = pts[:, :2] - pts[:, :2].mean(axis=0)
    _, axes = np.linalg.eigh(np.cov(xy.T))
    along = xy @ axes  # [M, 2]
    top = _percentiles(pts[:, 2], (TOP_PERCENTILE,))[0]
    first = _percentiles(along[:, 0], (100 - EDGE_PERCENTILE, EDGE_PERCENTILE))
    second = _percentiles(along[:, 1], (100 - EDGE_PERCENTILE, EDGE_PERCENTILE))
    height = top - table_z
    spans = (first[0] - first[1], second[0] - second[1])
    edges = sorted((spans[0], spans[1], height), reverse=True)
    if edges[2] <= 0:
        return None
    return edges[0], edges[1], edges[2]


def _percentiles(values: npt.NDArray[np.float64], percents: tuple[float, ...]) -> list[float]:
    """``np.percentile(values, percents)`` (its default "linear" method) for finite ``values``,
    bit for bit: numpy's virtual index ``(n - 1) * (p / 100)``, the order statistics either
    side of it from one partial sort, and numpy's own interpolation (``a + (b - a) * g``, or
    ``b - (b - a) * (1 - g)`` from ``g >= 0.5``), in the same IEEE operations on Python floats.

    Why not ``np.percentile``: its argument handling cost more than the partial sort itself,
    and the robot measures every ROI of every frame (``tests/test_size_cue.py`` pins the values
    against ``np.percentile``)."""
    n = len(values)
    positions = [(n - 1) * (p / 100) for p in percents]
    below = [min(math.floor(v), n - 1) for v in positions]
    ranks = sorted({*below, *(min(b + 1, n - 1) for b in below)})
    ordered = np.partition(values, ranks)
    out: list[float] = []
    for v, b in zip(positions, below, strict=True):
        if v >= n - 1:  # numpy takes the largest value
            out.append(float(ordered[n - 1]))
            continue
        a, c = float(ordered[b]), float(ordered[b + 1])
        g = v - b
        out.append(c - (c - a) * (1 - g) if g >= 0.5 else a + (c - a) * g)
    return out
