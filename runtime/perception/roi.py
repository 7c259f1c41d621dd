"""Regions of interest: one candidate object in the image, as a mask and a box.

ROIs are what the grounding ranks and what the grasp networks are restricted to; the box is also
what the static benchmark scores (IoU >= 0.5 with the target's box).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

BoolMask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class ROI:
    """A connected image region. ``label`` is the simulator body id for oracle ROIs, else None."""

    box_xywh: tuple[int, int, int, int]  # x, y of the top-left pixel, width, height (pixels)
    mask: BoolMask  # [H, W]
    area: int  # pixels in the mask
    centroid: tuple[float, float]  # (x, y) = (column, row) mean of the mask
    label: int | None = None


def roi_from_mask(mask: BoolMask, label: int | None = None) -> ROI:
    """Box, area and centroid of a non-empty mask."""
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        raise ValueError("cannot make an ROI from an empty mask")
    x0, x1 = int(cols.min()), int(cols.max())
    y0, y1 = int(rows.min()), int(rows.max())
    return ROI(
        box_xywh=(x0, y0, x1 - x0 + 1, y1 - y0 + 1),
        mask=mask,
        area=int(rows.size),
        centroid=(float(cols.mean()), float(rows.mean())),
        label=label,
    )


def box_iou(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    """Intersection over union of two pixel boxes (x, y, w, h)."""
    ax0, ay0, aw, ah = a
    bx0, by0, bw, bh = b
    ix = max(0, min(ax0 + aw, bx0 + bw) - max(ax0, bx0))
    iy = max(0, min(ay0 + ah, by0 + bh) - max(ay0, by0))
    inter = ix * iy
    union = aw * ah + bw * bh - inter
    return inter / union if union > 0 else 0.0


def mask_iou(a: BoolMask, b: BoolMask) -> float:
    union = int(np.count_nonzero(a | b))
    return int(np.count_nonzero(a & b)) / union if union else 0.0


def best_box_matches(predicted: Sequence[ROI], reference: Sequence[ROI]) -> list[float]:
    """For each reference ROI, the best box IoU any predicted ROI achieves (0 if none)."""
    return [
        max((box_iou(r.box_xywh, q.box_xywh) for q in predicted), default=0.0) for r in reference
    ]
