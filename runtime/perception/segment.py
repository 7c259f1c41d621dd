"""Class-agnostic RGB-D segmentation of a tabletop into object ROIs.

Steps: fit the table plane to the depth points (RANSAC), mark pixels a few millimetres above it,
add pixels that sit on the plane but do not look like the table (the colour cue), label connected
components and drop small blobs. The height threshold is low (5 mm) because flat tools such as
knives, scissors and screwdrivers rise only 1-2 cm above the table; the colour cue recovers their
thinnest parts (a blade lying flat) which depth alone cannot separate from a noisy table. Touching
objects are not split: scenes are sampled with a margin between objects, so it is rarely needed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from .observation import Observation
from .plane import Plane, PlaneFitConfig, fit_plane
from .roi import BoolMask, Region, roi_from_mask

_EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True)
class SegmentConfig:
    """Thresholds, in metres and pixels."""

    height_threshold: float = 0.005  # above-plane height that marks an object pixel
    colour_cue: bool = True
    colour_distance: float = 45.0  # RGB distance from the table's median colour (0-255 scale)
    colour_spread_factor: float = 4.0  # or this many robust spreads, whichever is larger
    colour_max_below: float = 0.003  # colour-cue pixels must not lie below the plane by more
    min_area: int = 150  # pixels; ~1.5 cm² at 0.7 m
    max_area_fraction: float = 0.3  # a blob this big is not one tabletop object
    fit_stride: int = 2  # use every n-th pixel in each direction for the plane fit
    plane: PlaneFitConfig = field(default_factory=PlaneFitConfig)


@dataclass(frozen=True)
class Segmentation:
    """The ROIs plus the intermediate maps, for debugging and for the grasp modules."""

    rois: list[Region]
    plane: Plane  # camera frame, oriented so heights above the table are positive
    height: npt.NDArray[np.float64]  # [H, W] metres above the plane (NaN = no depth)
    foreground: BoolMask  # [H, W] before component filtering


def table_plane(
    obs: Observation, config: SegmentConfig, points: npt.NDArray[np.float64] | None = None
) -> Plane:
    """The dominant plane in the camera frame, oriented towards the camera (``points``: the
    frame's ``points_camera()`` if already computed)."""
    pts = obs.points_camera() if points is None else points
    plane, _ = fit_plane(pts[:: config.fit_stride, :: config.fit_stride].reshape(-1, 3), config.plane)
    return plane.facing(np.zeros(3))


def _colour_foreground(
    rgb: npt.NDArray[np.uint8], on_table: BoolMask, near_plane: BoolMask, config: SegmentConfig
) -> BoolMask:
    """Pixels at table height whose colour is unlike the table's.

    The table colour model is the median of the pixels that lie on the plane, with a robust
    spread (median absolute deviation) so a textured table raises its own threshold.
    """
    colours = rgb[on_table]  # [n, 3] uint8
    n = len(colours)
    if n == 0:
        return np.zeros(near_plane.shape, dtype=bool)
    # Exact integer arithmetic on doubled values (the median of integers is a multiple of 1/2):
    # the same median, spread and comparisons as in float64, without float copies of the image.
    median2 = np.array([_doubled_median(colours[:, c], n) for c in range(3)], dtype=np.int64)  # [3]
    dist4 = _doubled_sq_distance(colours, median2)  # [n] 4 x squared distance, exact
    middle = np.partition(dist4, [(n - 1) // 2, n // 2])  # the median's two middle ranks
    mad = (np.sqrt(middle[(n - 1) // 2] / 4.0) + np.sqrt(middle[n // 2] / 4.0)) / 2.0
    threshold = max(config.colour_distance, config.colour_spread_factor * 1.4826 * float(mad))
    odd = (_doubled_sq_distance(rgb, median2) > 4.0 * threshold**2) & near_plane  # [H, W]
    # colour alone is noisy at object borders and texture speckles: keep only solid regions
    opened: BoolMask = ndimage.binary_opening(odd, structure=_EIGHT_CONNECTED)
    return opened


def _doubled_median(values: npt.NDArray[np.uint8], n: int) -> int:
    """Twice the median of ``n`` uint8 values (an integer), from their histogram."""
    cum = np.cumsum(np.bincount(values, minlength=256))
    low = int(np.searchsorted(cum, (n - 1) // 2 + 1))  # value of rank (n - 1) // 2
    high = int(np.searchsorted(cum, n // 2 + 1))  # value of rank n // 2
    return low + high


def _doubled_sq_distance(rgb: npt.NDArray[np.uint8], median2: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """``4 * |rgb - median|^2`` per pixel ``[...]``, exact in integers."""
    d = 2 * rgb.astype(np.int32) - median2.astype(np.int32)  # [..., 3]
    out: npt.NDArray[np.int64] = np.einsum("...c,...c->...", d, d).astype(np.int64)
    return out


def segment(obs: Observation, config: SegmentConfig | None = None) -> Segmentation:
    """ROIs of everything standing on the table, in raster order of their first pixel."""
    cfg = config or SegmentConfig()
    points = obs.points_camera()  # [H, W, 3], once for the plane fit and the heights
    plane = table_plane(obs, cfg, points)
    height = plane.distance(points)  # [H, W], NaN where depth is invalid
    valid = np.isfinite(height)
    above = valid & (np.nan_to_num(height, nan=-1.0) > cfg.height_threshold)
    foreground = above
    if cfg.colour_cue:
        h = np.nan_to_num(height, nan=-1.0)
        on_table = valid & (np.abs(h) <= cfg.plane.inlier_threshold)
        near_plane = valid & (h >= -cfg.colour_max_below) & ~above
        foreground = above | _colour_foreground(obs.rgb, on_table, near_plane, cfg)
    labels, count = ndimage.label(foreground, structure=_EIGHT_CONNECTED)
    max_area = cfg.max_area_fraction * foreground.size
    areas = np.bincount(labels.ravel(), minlength=count + 1)
    rois: list[Region] = []
    for index, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None or areas[index] < cfg.min_area or areas[index] > max_area:
            continue
        rois.append(roi_from_mask(_filled(labels, index, box)))
    return Segmentation(rois=rois, plane=plane, height=height, foreground=foreground)


def _filled(labels: npt.NDArray[np.int32], index: int, box: tuple[slice, slice]) -> BoolMask:
    """Component ``index`` as a full-frame mask with its holes filled, computed on its bounding
    box padded by one pixel: a hole cannot reach outside the box, so this equals filling the
    whole frame at a fraction of the cost."""
    rows, cols = box
    h, w = labels.shape
    r0, r1 = max(rows.start - 1, 0), min(rows.stop + 1, h)
    c0, c1 = max(cols.start - 1, 0), min(cols.stop + 1, w)
    crop = np.pad(labels[r0:r1, c0:c1] == index, 1)  # padding: the outside is never a hole
    mask = np.zeros(labels.shape, dtype=bool)
    mask[r0:r1, c0:c1] = ndimage.binary_fill_holes(crop)[1:-1, 1:-1]
    return mask


def segment_rois(obs: Observation, config: SegmentConfig | None = None) -> list[Region]:
    """Just the ROIs (see ``segment``)."""
    return segment(obs, config).rois
