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


def table_plane(obs: Observation, config: SegmentConfig) -> Plane:
    """The dominant plane in the camera frame, oriented towards the camera."""
    pts = obs.points_camera()[:: config.fit_stride, :: config.fit_stride].reshape(-1, 3)
    plane, _ = fit_plane(pts, config.plane)
    return plane.facing(np.zeros(3))


def _colour_foreground(
    rgb: npt.NDArray[np.uint8], on_table: BoolMask, near_plane: BoolMask, config: SegmentConfig
) -> BoolMask:
    """Pixels at table height whose colour is unlike the table's.

    The table colour model is the median of the pixels that lie on the plane, with a robust
    spread (median absolute deviation) so a textured table raises its own threshold.
    """
    colours = rgb[on_table].astype(np.float64)  # [n, 3]
    if len(colours) == 0:
        return np.zeros(near_plane.shape, dtype=bool)
    median = np.median(colours, axis=0)
    mad = float(np.median(np.linalg.norm(colours - median, axis=1)))
    threshold = max(config.colour_distance, config.colour_spread_factor * 1.4826 * mad)
    distance = np.linalg.norm(rgb.astype(np.float64) - median, axis=-1)
    odd = (distance > threshold) & near_plane
    # colour alone is noisy at object borders and texture speckles: keep only solid regions
    opened: BoolMask = ndimage.binary_opening(odd, structure=_EIGHT_CONNECTED)
    return opened


def segment(obs: Observation, config: SegmentConfig | None = None) -> Segmentation:
    """ROIs of everything standing on the table, in raster order of their first pixel."""
    cfg = config or SegmentConfig()
    plane = table_plane(obs, cfg)
    height = plane.distance(obs.points_camera())  # [H, W], NaN where depth is invalid
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
    rois: list[Region] = []
    for index in range(1, count + 1):
        mask = labels == index
        area = int(np.count_nonzero(mask))
        if area < cfg.min_area or area > max_area:
            continue
        rois.append(roi_from_mask(ndimage.binary_fill_holes(mask)))
    return Segmentation(rois=rois, plane=plane, height=height, foreground=foreground)


def segment_rois(obs: Observation, config: SegmentConfig | None = None) -> list[Region]:
    """Just the ROIs (see ``segment``)."""
    return segment(obs, config).rois
