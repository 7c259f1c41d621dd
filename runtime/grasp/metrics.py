"""The Cornell grasp-rectangle metric (Jiang et al. 2011; used by GG-CNN, GR-ConvNet, Chu et al.).

A predicted grasp counts as correct if, against *any* ground-truth rectangle, the angle differs by
less than 30° (modulo 180°: a parallel gripper is symmetric) and the Jaccard index (IoU) of the two
rectangles exceeds 0.25. The IoU here is exact — convex-polygon clipping — rather than the
rasterised approximation of the original code, so it does not depend on an image size.

Rectangles are ``[4, 2]`` arrays of ``(x, y)`` corners in Cornell order (p0→p1 along the closing
axis), or ``Grasp2D`` objects.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from .geometry import Grasp2D, wrap_half_pi

FloatArray = npt.NDArray[np.float64]
RectLike = Grasp2D | npt.ArrayLike

ANGLE_THRESHOLD_RAD = math.pi / 6  # 30°
IOU_THRESHOLD = 0.25


def rect_corners(
    center_xy: tuple[float, float], angle_rad: float, width_px: float, length_px: float
) -> FloatArray:
    """(centre, angle, opening, jaw size) → corners ``[4, 2]``."""
    return Grasp2D(center_xy, angle_rad, width_px, length_px, 1.0).corners()


def as_corners(rect: RectLike) -> FloatArray:
    """Accept a ``Grasp2D`` or anything shaped ``[4, 2]``."""
    if isinstance(rect, Grasp2D):
        return rect.corners()
    c = np.asarray(rect, dtype=np.float64)
    if c.shape != (4, 2):
        raise ValueError(f"a rectangle needs 4 (x, y) corners, got shape {c.shape}")
    return c


def rectangle_angle(rect: RectLike) -> float:
    """Closing-axis angle of a rectangle (edge p0→p1), in ``[-pi/2, pi/2)``."""
    if isinstance(rect, Grasp2D):
        return wrap_half_pi(rect.angle_rad)
    c = as_corners(rect)
    d = c[1] - c[0]
    return wrap_half_pi(math.atan2(-float(d[1]), float(d[0])))


def angle_difference(a: float, b: float) -> float:
    """Absolute difference of two grasp angles modulo pi, in ``[0, pi/2]``."""
    return abs(wrap_half_pi(a - b))


def polygon_area(poly: FloatArray) -> float:
    """Shoelace area of a simple polygon ``[N, 2]`` (0 for fewer than 3 vertices)."""
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _ccw(poly: FloatArray) -> FloatArray:
    x, y = poly[:, 0], poly[:, 1]
    signed = float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    return poly if signed >= 0 else poly[::-1]


def _clip_half_plane(
    poly: list[tuple[float, float]], a: FloatArray, b: FloatArray
) -> list[tuple[float, float]]:
    """Keep the part of ``poly`` left of the directed line a→b (inside of a CCW clip edge)."""
    ex, ey = float(b[0] - a[0]), float(b[1] - a[1])
    sides = [ex * (p[1] - float(a[1])) - ey * (p[0] - float(a[0])) for p in poly]
    out: list[tuple[float, float]] = []
    for j, p in enumerate(poly):
        q = poly[(j + 1) % len(poly)]
        sp, sq = sides[j], sides[(j + 1) % len(poly)]
        if sp >= 0:
            out.append(p)
        if (sp >= 0) != (sq >= 0):
            t = sp / (sp - sq)
            out.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
    return out


def clip_convex_polygon(subject: FloatArray, clip: FloatArray) -> FloatArray:
    """Sutherland–Hodgman: the part of ``subject`` inside the convex polygon ``clip``."""
    out = [(float(x), float(y)) for x, y in _ccw(subject)]
    c = _ccw(clip)
    for i in range(len(c)):
        if not out:
            break
        out = _clip_half_plane(out, c[i], c[(i + 1) % len(c)])
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def rectangle_iou(a: RectLike, b: RectLike) -> float:
    """Exact Jaccard index of two rectangles (any convex quadrilaterals)."""
    pa, pb = as_corners(a), as_corners(b)
    inter = polygon_area(clip_convex_polygon(pa, pb))
    union = polygon_area(pa) + polygon_area(pb) - inter
    return inter / union if union > 0 else 0.0


def max_iou(
    pred: RectLike, ground_truth: Iterable[RectLike], angle_threshold: float | None = None
) -> float:
    """Best IoU of ``pred`` against the ground truth (optionally only angle-compatible ones)."""
    best = 0.0
    ang = rectangle_angle(pred)
    for gt in ground_truth:
        if angle_threshold is not None and angle_difference(ang, rectangle_angle(gt)) >= (
            angle_threshold
        ):
            continue
        best = max(best, rectangle_iou(pred, gt))
    return best


def grasp_success(
    pred: RectLike,
    ground_truth: Iterable[RectLike],
    angle_threshold: float = ANGLE_THRESHOLD_RAD,
    iou_threshold: float = IOU_THRESHOLD,
) -> bool:
    """Cornell criterion: some ground truth within the angle threshold with IoU above 0.25."""
    return max_iou(pred, ground_truth, angle_threshold) > iou_threshold


def load_cornell_rectangles(path: Path) -> FloatArray:
    """Read a Cornell-style annotation file: 4 lines ``x y`` per rectangle → ``[N, 4, 2]``.

    Rectangles with NaN corners (present in the original Cornell files) are dropped; a line that
    does not hold two numbers, or a count of lines not divisible by 4, is an error naming the file
    and line, because silently misaligned corners would corrupt every later rectangle.
    """
    points: list[tuple[float, float]] = []
    with path.open(encoding="utf-8") as handle:
        for lineno, line in enumerate(handle, start=1):
            fields = line.split()
            if not fields:
                continue
            if len(fields) != 2:
                raise ValueError(f"{path}:{lineno}: expected 'x y', got {line.strip()!r}")
            try:
                points.append((float(fields[0]), float(fields[1])))
            except ValueError:
                raise ValueError(f"{path}:{lineno}: not numbers: {line.strip()!r}") from None
    if len(points) % 4:
        raise ValueError(f"{path}: {len(points)} corner lines, not a multiple of 4")
    rects = np.array(points, dtype=np.float64).reshape(-1, 4, 2)
    keep = np.isfinite(rects).all(axis=(1, 2))
    return rects[keep]


def success_rate(
    predictions: Sequence[RectLike | None], ground_truths: Sequence[Iterable[RectLike]]
) -> float:
    """Fraction of scenes whose (top) prediction is correct; a missing prediction counts as wrong."""
    if len(predictions) != len(ground_truths):
        raise ValueError("predictions and ground_truths differ in length")
    if not predictions:
        return 0.0
    hits = sum(
        p is not None and grasp_success(p, gt)
        for p, gt in zip(predictions, ground_truths, strict=True)
    )
    return hits / len(predictions)
