"""The segmenter's faster parts give the same pixels and numbers as the plain versions.

Why: ``segment`` was sped up (np.cross written out in the RANSAC loop, the colour cue by
per-channel gathers and a per-channel int32 distance, the 3x3 opening by shifted slices, ROI
geometry scanned inside the component's box). Each must equal the straightforward code it
replaced exactly (bit for bit, pixel for pixel), or the ROIs, and every result built on them,
would move. The references below are the replaced implementations.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from craft_e.runtime.perception.plane import _plane_through
from craft_e.runtime.perception.roi import roi_from_mask
from craft_e.runtime.perception.segment import (
    _EIGHT_CONNECTED,
    SegmentConfig,
    _colour_foreground,
    _distances_and_table_counts,
    _table_histograms,
    _value_at_rank,
    open_3x3,
)


def _reference_colour_foreground(rgb: np.ndarray, on_table: np.ndarray, near_plane: np.ndarray,
                                 config: SegmentConfig) -> np.ndarray:
    """The replaced version: [n, 3] gather, einsum distances, scipy's opening."""
    colours = rgb[on_table]
    n = len(colours)
    if n == 0:
        return np.zeros(near_plane.shape, dtype=bool)

    def dist(x: np.ndarray, median2: np.ndarray) -> np.ndarray:
        d = 2 * x.astype(np.int32) - median2.astype(np.int32)
        return np.einsum("...c,...c->...", d, d).astype(np.int64)

    median2 = np.array([int(2 * np.median(colours[:, c].astype(np.float64))) for c in range(3)], dtype=np.int64)
    dist4 = dist(colours, median2)
    middle = np.partition(dist4, [(n - 1) // 2, n // 2])
    mad = (np.sqrt(middle[(n - 1) // 2] / 4.0) + np.sqrt(middle[n // 2] / 4.0)) / 2.0
    threshold = max(config.colour_distance, config.colour_spread_factor * 1.4826 * float(mad))
    odd = (dist(rgb, median2) > 4.0 * threshold**2) & near_plane
    return np.asarray(ndimage.binary_opening(odd, structure=_EIGHT_CONNECTED))


@pytest.mark.parametrize("shape", [(1, 1), (2, 5), (3, 3), (4, 7), (60, 80)])
@pytest.mark.parametrize("density", [0.3, 0.7, 0.95])
def test_open_3x3_equals_scipy(shape: tuple[int, int], density: float) -> None:
    rng = np.random.default_rng(int(density * 100) + shape[0])
    mask = rng.random(shape) < density
    want = ndimage.binary_opening(mask, structure=_EIGHT_CONNECTED)
    assert np.array_equal(open_3x3(mask), want)


@pytest.mark.parametrize("seed", range(6))
def test_colour_foreground_equals_the_reference(seed: int) -> None:
    """Textured tables (noise of several strengths) with coloured patches, random geometry."""
    rng = np.random.default_rng(seed)
    h, w = 90, 120
    base = rng.integers(60, 200, 3)
    rgb = np.clip(base + rng.normal(0, 3 + 3 * seed, (h, w, 3)), 0, 255).astype(np.uint8)
    for _ in range(4):
        y, x = rng.integers(0, h - 10), rng.integers(0, w - 10)
        rgb[y : y + rng.integers(3, 20), x : x + rng.integers(3, 30)] = rng.integers(0, 256, 3)
    on_table = rng.random((h, w)) < 0.6
    near_plane = on_table | (rng.random((h, w)) < 0.5)
    cfg = SegmentConfig(colour_distance=15.0 + 3 * seed)
    got = _colour_foreground(rgb, on_table, near_plane, cfg)
    assert got.any()  # patches found: the comparison is not between two empty masks
    assert np.array_equal(got, _reference_colour_foreground(rgb, on_table, near_plane, cfg))
    none = np.zeros((h, w), dtype=bool)
    assert not _colour_foreground(rgb, none, near_plane, cfg).any()


def test_plane_through_is_np_cross_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    for scale in (1e-3, 1.0, 1e3):
        for _ in range(2000):
            pts = rng.normal(size=(3, 3)) * scale
            normal = np.cross(pts[1] - pts[0], pts[2] - pts[0])
            normal = normal / float(np.linalg.norm(normal))
            plane = _plane_through(pts)
            assert plane is not None
            assert np.array_equal(plane.normal, normal) and plane.offset == -float(normal @ pts[0])
    assert _plane_through(np.zeros((3, 3))) is None


def test_roi_from_mask_within_a_window_is_the_same() -> None:
    rng = np.random.default_rng(1)
    mask = np.zeros((50, 70), dtype=bool)
    mask[12:30, 20:41] = rng.random((18, 21)) < 0.5
    mask[12, 20] = mask[29, 40] = True
    full = roi_from_mask(mask, label=3)
    for within in ((slice(12, 30), slice(20, 41)), (slice(5, 40), slice(0, 70)), (slice(None), slice(None))):
        part = roi_from_mask(mask, label=3, within=within)
        assert part.box_xywh == full.box_xywh and part.area == full.area
        assert part.centroid == full.centroid and part.mask is mask


@pytest.mark.parametrize("n", [1, 2, 3, 10, 11, 1000, 1001])
def test_histogram_medians_are_twice_numpy_median(n: int) -> None:
    """The colour cue reads twice each channel's median off the table pixels' histograms (the sum
    of the two middle ranks): exact for odd and even counts, skewed and flat value spreads."""
    rng = np.random.default_rng(n)
    for values in (rng.integers(0, 256, n, dtype=np.uint8), (rng.random(n) ** 4 * 255).astype(np.uint8)):
        rgb = np.ascontiguousarray(np.stack([values, values[::-1], values // 3], axis=-1)[None])  # [1, n, 3]
        counts = _table_histograms(rgb, np.ones((1, n), dtype=bool))
        for c in range(3):
            doubled = _value_at_rank(counts[c], (n - 1) // 2) + _value_at_rank(counts[c], n // 2)
            assert doubled == int(2 * np.median(rgb[0, :, c].astype(np.float64)))


def test_doubled_sq_distance_is_exact_at_the_extremes() -> None:
    """Every channel value against doubled medians from 0 to 510 (odd ones too: half-integer
    medians), equal to the float64 formula; the largest, 3 x 510^2, still fits int32; the
    table pixels' distances are counted exactly."""
    values = np.arange(256, dtype=np.uint8)
    rgb = np.stack(np.broadcast_arrays(values[:, None], values[::-1][:, None], values[:, None] // 2), -1)
    rgb = np.ascontiguousarray(np.broadcast_to(rgb, (256, 3, 3)))  # [256, 3, 3]
    table = np.random.default_rng(0).random((256, 3)) < 0.5
    for median2 in ([0, 0, 0], [510, 510, 510], [255, 1, 509], [301, 290, 270]):
        m = np.array(median2, dtype=np.int64)
        got, counts = _distances_and_table_counts(rgb, m, table)
        want = (((2.0 * rgb.astype(np.float64) - m) ** 2).sum(axis=-1))
        assert got.dtype == np.int32 and np.array_equal(got, want.astype(np.int64))
        assert np.array_equal(counts, np.bincount(got[table], minlength=len(counts)))
    full, _ = _distances_and_table_counts(np.zeros((1, 1, 3), np.uint8), np.array([510, 510, 510]),
                                          np.ones((1, 1), dtype=bool))
    assert int(full[0, 0]) == 3 * 510**2
