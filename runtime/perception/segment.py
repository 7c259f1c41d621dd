"""Class-agnostic RGB-D segmentation of a tabletop into object ROIs.

Steps: fit the table plane to the depth points (RANSAC), mark pixels a few millimetres above it,
add pixels that sit on the plane but do not look like the table (the colour cue), label connected
components and drop small blobs. The height threshold is low (5 mm) because flat tools such as
knives, scissors and screwdrivers rise only 1-2 cm above the table; the colour cue recovers their
thinnest parts (a blade lying flat) which depth alone cannot separate from a noisy table.

Objects that touch in the image are one component. Straight above the table that is rare (the
testbed samples scenes with a margin between objects), but a camera that looks at the table
from an angle sees near objects overlap far ones. ``SegmentConfig.split_on_table`` then splits a
component whose raised points form separate clusters on the table plane (``split_on_table``): two
objects that stand apart on the table are two regions, however they overlap in the image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
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
    #: Split a region whose raised points form clusters apart on the table plane (``split_on_table``).
    #: Off for the testbed's evaluations, whose published tables were made without it; on for a
    #: camera's frames (``frame.perceive``), which may look at the table from an angle.
    split_on_table: bool = False
    #: the table-plane grid's cell (m): clusters at least about one cell apart are split
    split_cell: float = 0.01


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
    plane, _ = fit_plane(pts[:: config.fit_stride, :: config.fit_stride], config.plane)  # a view: no copy
    return plane.facing(np.zeros(3))


def _colour_foreground(
    rgb: npt.NDArray[np.uint8], on_table: BoolMask, near_plane: BoolMask, config: SegmentConfig
) -> BoolMask:
    """Pixels at table height whose colour is unlike the table's.

    The table colour model is the median of the pixels that lie on the plane, with a robust
    spread (median absolute deviation) so a textured table raises its own threshold.

    Exact integer arithmetic on doubled values (the median of integers is a multiple of 1/2): the
    same median, spread and comparisons as in float64. The medians are read off histograms
    (counts of each colour value, then of each squared distance, over the table's pixels),
    built in two compiled passes over the frame: the same integers as partial sorts of the
    gathered pixels, ~4x faster (every frame pays for it; ``tests/test_perception_segment_fast.py``).
    """
    n = int(np.count_nonzero(on_table))
    if n == 0:
        return np.zeros(near_plane.shape, dtype=bool)
    rgb = np.ascontiguousarray(rgb)
    table = np.ascontiguousarray(on_table)
    middle = ((n - 1) // 2, n // 2)  # the median's two middle ranks
    channels = _table_histograms(rgb, table)  # [3, 256]
    median2 = np.array([_value_at_rank(channels[c], middle[0]) + _value_at_rank(channels[c], middle[1])
                        for c in range(3)], dtype=np.int64)  # [3] twice the median
    dist4_image, counts = _distances_and_table_counts(rgb, median2, table)  # [H, W] 4 x squared distance
    low, high = _value_at_rank(counts, middle[0]), _value_at_rank(counts, middle[1])
    mad = (np.sqrt(low / 4.0) + np.sqrt(high / 4.0)) / 2.0
    threshold = max(config.colour_distance, config.colour_spread_factor * 1.4826 * float(mad))
    odd = (dist4_image > 4.0 * threshold**2) & near_plane  # [H, W]
    # colour alone is noisy at object borders and texture speckles: keep only solid regions
    return open_3x3(odd)


def _value_at_rank(counts: npt.NDArray[np.int64], rank: int) -> int:
    """The value of 0-based ``rank`` among values counted by ``counts`` (value -> count)."""
    return int(_rank_kernel(counts, rank))


@numba.njit(cache=True)
def _rank_kernel(counts: npt.NDArray[np.int64], rank: int) -> int:  # pragma: no cover - compiled
    seen = 0
    for value in range(counts.shape[0]):
        seen += counts[value]
        if seen > rank:
            return value
    last: int = counts.shape[0] - 1
    return last


@numba.njit(cache=True)
def _table_histograms(rgb: npt.NDArray[np.uint8], on_table: BoolMask) -> npt.NDArray[np.int64]:  # pragma: no cover
    """How many of the ``on_table`` pixels have each value, per channel ``[3, 256]``."""
    counts = np.zeros((3, 256), dtype=np.int64)
    h, w = on_table.shape
    for i in range(h):
        for j in range(w):
            if on_table[i, j]:
                counts[0, rgb[i, j, 0]] += 1
                counts[1, rgb[i, j, 1]] += 1
                counts[2, rgb[i, j, 2]] += 1
    return counts


#: 4 x the largest squared RGB distance, (2 x 255)^2 per channel
_MAX_DIST4 = 3 * 510**2


@numba.njit(cache=True)
def _distances_and_table_counts(
    rgb: npt.NDArray[np.uint8], median2: npt.NDArray[np.int64], on_table: BoolMask,
) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.int64]]:  # pragma: no cover - compiled
    """``4 * |rgb - median|^2`` per pixel ``[H, W]`` (``median2``: twice the median colour), exact
    in integers (at most ``_MAX_DIST4``, so int32), and how many ``on_table`` pixels have each of
    its values ``[_MAX_DIST4 + 1]``."""
    h, w = on_table.shape
    out = np.empty((h, w), dtype=np.int32)
    counts = np.zeros(_MAX_DIST4 + 1, dtype=np.int64)
    m0, m1, m2 = median2[0], median2[1], median2[2]
    for i in range(h):
        for j in range(w):
            d0 = 2 * np.int64(rgb[i, j, 0]) - m0
            d1 = 2 * np.int64(rgb[i, j, 1]) - m1
            d2 = 2 * np.int64(rgb[i, j, 2]) - m2
            d = d0 * d0 + d1 * d1 + d2 * d2
            out[i, j] = d
            if on_table[i, j]:
                counts[d] += 1
    return out, counts


def open_3x3(mask: BoolMask) -> BoolMask:
    """``ndimage.binary_opening(mask, structure=np.ones((3, 3)))`` (outside the image counts as
    background), as separable AND / OR of shifted slices: the same pixels, ~15x faster.

    Erosion keeps a pixel whose 3x3 neighbourhood lies wholly inside the mask (never one on the
    image border); dilation then marks every pixel within one step (8-connected) of a kept one.
    """
    eroded = np.zeros_like(mask)
    rows = mask[:-2] & mask[1:-1] & mask[2:]  # [H-2, W]: vertical AND around rows 1..H-2
    eroded[1:-1, 1:-1] = rows[:, :-2] & rows[:, 1:-1] & rows[:, 2:]
    grown = eroded.copy()
    grown[1:] |= eroded[:-1]
    grown[:-1] |= eroded[1:]
    out = grown.copy()
    out[:, 1:] |= grown[:, :-1]
    out[:, :-1] |= grown[:, 1:]
    return out


def segment(obs: Observation, config: SegmentConfig | None = None, keep: BoolMask | None = None,
            plane: Plane | None = None) -> Segmentation:
    """ROIs of everything standing on the table, in raster order of their first pixel; with
    ``keep`` (H x W), only of its pixels (a robot's workspace: ``perception/workspace.py``). The
    table plane is fitted to the whole frame either way, unless the caller has fitted it already
    (``plane``: ``table_plane(obs, config)``, in the camera frame; a camera's frame is checked
    against its plane before it is perceived, ``frame.observe_frame``)."""
    cfg = config or SegmentConfig()
    points = obs.points_camera()  # [H, W, 3], once for the plane fit and the heights
    plane = plane if plane is not None else table_plane(obs, cfg, points)
    height = plane.distance(points)  # [H, W], NaN where depth is invalid
    # a comparison with NaN is False, so pixels without depth are in none of these masks
    above = height > cfg.height_threshold
    foreground = above
    if cfg.colour_cue:
        on_table = np.abs(height) <= cfg.plane.inlier_threshold
        near_plane = (height >= -cfg.colour_max_below) & ~above
        foreground = above | _colour_foreground(obs.rgb, on_table, near_plane, cfg)
    if keep is not None:
        foreground = foreground & keep
    labels, _ = ndimage.label(foreground, structure=_EIGHT_CONNECTED)
    max_area = cfg.max_area_fraction * foreground.size
    rois: list[Region] = []
    for index, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        # counted inside the component's box (every pixel of it lies there): the same count as a
        # histogram of the whole label image, without converting 300k labels to 64-bit indices
        area = int(np.count_nonzero(labels[box] == index))
        if area < cfg.min_area or area > max_area:
            continue
        mask, within = _filled(labels, index, box)
        whole = roi_from_mask(mask, within=within)
        if cfg.split_on_table:
            component = np.zeros(labels.shape, dtype=bool)
            component[box] = labels[box] == index
            rois.extend(split_on_table(component, points, height, plane, cfg, box) or [whole])
        else:
            rois.append(whole)
    if cfg.split_on_table:  # the parts of a split region, in raster order of their first pixel too
        rois.sort(key=_first_pixel)
    return Segmentation(rois=rois, plane=plane, height=height, foreground=foreground)


def split_on_table(mask: BoolMask, points: npt.NDArray[np.float64], height: npt.NDArray[np.float64],
                   plane: Plane, config: SegmentConfig, within: tuple[slice, slice] | None = None) -> list[Region]:
    """The parts of the connected component ``mask`` when its raised pixels form clusters apart
    on the table, each with its holes filled; ``[]`` when it is one object (the caller keeps its
    region as it was). The component's own pixels, not its hole-filled mask: a hole may hold
    another component (a skillet lid's knob inside its ring), which is a region of its own.

    Each raised pixel's point (``points``, camera frame) is laid on ``plane`` and binned in a grid of
    ``config.split_cell``; the grid's occupied cells are labelled 8-connected, and each cluster of
    at least ``min_area`` pixels becomes a region, with the component's other pixels (flat ones the
    colour cue added, smaller clusters) joining the part nearest them in the image, and its holes
    filled. Why: a camera at an angle sees a near object overlap a far one in the image, one
    component, although on the table they stand centimetres apart (on sim-dev scenes seen from 45
    degrees, 6 of 10 missed targets were merged so in an ad hoc count;
    ``benchmarks/bench_frame_views.py`` measures what the split changes).
    An object seen whole is one cluster: its visible surfaces all lie over its own footprint.

    ``within``: a (row, column) window known to hold the whole component (its box), to which the
    work is cropped; the same parts, without passes over the whole frame."""
    frame_shape = mask.shape
    if within is not None:
        row_off, col_off = within[0].start or 0, within[1].start or 0
        mask, points, height = mask[within], points[within], height[within]
    else:
        row_off = col_off = 0
    raised = mask & (height > config.height_threshold)  # NaN heights: False
    rows, cols = np.nonzero(raised)
    if len(rows) < 2 * config.min_area:  # no room for two parts
        return []
    on_plane = points[rows, cols]  # [n, 3]
    first, second = _plane_axes(np.asarray(plane.normal, dtype=np.float64))
    cells = np.floor(np.stack([on_plane @ first, on_plane @ second], axis=1) / config.split_cell).astype(np.int64)
    cells -= cells.min(axis=0)
    grid = np.zeros(tuple(int(v) + 1 for v in cells.max(axis=0)), dtype=bool)
    grid[cells[:, 0], cells[:, 1]] = True
    clusters, count = ndimage.label(grid, structure=_EIGHT_CONNECTED)
    if count <= 1:
        return []
    member = clusters[cells[:, 0], cells[:, 1]]  # [n]: each raised pixel's cluster
    sizes = np.bincount(member, minlength=count + 1)
    kept = [k for k in range(1, count + 1) if sizes[k] >= config.min_area]
    if len(kept) <= 1:
        return []
    # every pixel of the component joins the part of its nearest kept raised pixel in the image:
    # the flat pixels the colour cue added (a blade lying flat) and those of clusters too small
    ys, xs = np.nonzero(mask)  # the component's box holds its raised pixels too
    r0, r1, c0, c1 = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
    seeds = np.zeros((r1 - r0, c1 - c0), dtype=np.int32)
    for n, k in enumerate(kept, start=1):
        seeds[rows[member == k] - r0, cols[member == k] - c0] = n
    _, (near_r, near_c) = ndimage.distance_transform_edt(seeds == 0, return_indices=True)
    owner = np.where(mask[r0:r1, c0:c1], seeds[near_r, near_c], 0)
    parts = []
    window = (slice(row_off + r0, row_off + r1), slice(col_off + c0, col_off + c1))  # in the frame
    for n in range(1, len(kept) + 1):
        part = np.zeros(frame_shape, dtype=bool)
        part[window] = fill_holes(np.pad(owner == n, 1))[1:-1, 1:-1]
        parts.append(roi_from_mask(part, within=window))
    return parts


def _plane_axes(normal: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Two unit axes on the plane of ``normal``, at right angles."""
    seed = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    first = seed - (seed @ normal) * normal
    first /= np.linalg.norm(first)
    return first, np.cross(normal, first)


def _first_pixel(region: Region) -> int:
    """The raster index of the region's first pixel: the first set pixel of its box's top row."""
    top = int(region.box_xywh[1])
    width = int(region.mask.shape[1])
    return top * width + int(np.argmax(region.mask[top]))


def _filled(
    labels: npt.NDArray[np.int32], index: int, box: tuple[slice, slice]
) -> tuple[BoolMask, tuple[slice, slice]]:
    """Component ``index`` as a full-frame mask with its holes filled, computed on its bounding
    box padded by one pixel: a hole cannot reach outside the box, so this equals filling the
    whole frame at a fraction of the cost. Also returns that padded box (it holds the mask)."""
    rows, cols = box
    h, w = labels.shape
    r0, r1 = max(rows.start - 1, 0), min(rows.stop + 1, h)
    c0, c1 = max(cols.start - 1, 0), min(cols.stop + 1, w)
    crop = np.pad(labels[r0:r1, c0:c1] == index, 1)  # padding: the outside is never a hole
    mask = np.zeros(labels.shape, dtype=bool)
    mask[r0:r1, c0:c1] = fill_holes(crop)[1:-1, 1:-1]
    return mask, (slice(r0, r1), slice(c0, c1))


def fill_holes(mask: BoolMask) -> BoolMask:
    """``ndimage.binary_fill_holes(mask)`` for a mask whose border pixels are all background
    (``_filled`` pads it so): the same pixels, one pass instead of a dilation repeated to convergence.

    A hole is background that the background outside cannot reach by 4-connected steps, which
    is what ``binary_fill_holes`` computes by dilating from the border until nothing changes. With
    the whole border background, the outside is the 4-connected background component holding the
    corner, so one labelling pass finds it: everything else is the object or a hole."""
    if mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any():
        raise ValueError("fill_holes needs a background border (pad the mask by one pixel)")
    background, _ = ndimage.label(~mask)  # 4-connected, binary_fill_holes' own structure
    filled: BoolMask = background != background[0, 0]
    return filled
