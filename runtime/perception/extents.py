"""An ROI's extents from depth: the three edges of its box in metres, longest first.

The size cue (``grounding/size_cue.py``) compares them with objects' typical sizes. From the
overhead camera the height is the top of the ROI's points above the table, and the footprint the
spread of those points along their two principal axes; percentiles rather than extremes, so a few
stray depth pixels at the mask's edge do not stretch the box. Sorted, so the pose does not matter.
"""

from __future__ import annotations

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
    # numpy's sum over an axis of length 3
    pts = pts[np.isfinite(pts[:, 0] + pts[:, 1] + pts[:, 2])]
    if len(pts) < MIN_POINTS:
        return None
    xy = pts[:, :2] - pts[:, :2].mean(axis=0)
    _, axes = np.linalg.eigh(np.cov(xy.T))
    along = xy @ axes  # [M, 2]
    # one percentile call for the three columns (height, both spans): the same order statistics
    # and interpolation as one call each, at a third of numpy's per-call cost (the robot measures
    # every ROI of every frame)
    q = np.percentile(np.column_stack([pts[:, 2], along]), [TOP_PERCENTILE, 100 - EDGE_PERCENTILE, EDGE_PERCENTILE],
                      axis=0)  # [3 percentiles, 3 columns]
    height = float(q[0, 0]) - table_z
    spans = q[1, 1:] - q[2, 1:]
    edges = sorted((float(spans[0]), float(spans[1]), height), reverse=True)
    if edges[2] <= 0:
        return None
    return edges[0], edges[1], edges[2]
