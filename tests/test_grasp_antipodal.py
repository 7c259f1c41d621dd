"""The analytic antipodal sampler on synthetic depth: thin objects are grasped across."""

from __future__ import annotations

import math

import numpy as np
import pytest

from craft_e.runtime.grasp.antipodal import (
    AntipodalConfig,
    _lookup,
    estimate_object_mask,
    sample_antipodal_grasps,
)
from craft_e.runtime.grasp.geometry import Grasp2D
from craft_e.runtime.grasp.metrics import angle_difference
from craft_e.runtime.grasp.predict import predict_grasps
from craft_e.runtime.grasp.synthetic import Box, bar_scene, table_scene

MAX_OPENING_M = 0.085


def _opening_m(g: Grasp2D, z: float, fx: float = 615.0) -> float:
    return g.width_px * z / fx


@pytest.mark.parametrize("bar_deg", [0.0, 30.0, 90.0, 135.0])
def test_thin_bar_is_grasped_across_on_the_bar(bar_deg: float) -> None:
    scene = bar_scene(angle_deg=bar_deg, width_m=0.015, height_m=0.012)
    mask = scene.masks[0]
    grasps = sample_antipodal_grasps(scene.depth, mask, scene.intrinsics, max_grasps=5)
    assert grasps
    best = grasps[0]
    across = math.radians(bar_deg + 90.0)
    assert math.degrees(angle_difference(best.angle_rad, across)) < 10.0
    for g in grasps:
        assert mask[round(g.center_xy[1]), round(g.center_xy[0])]
        assert 0.0 < g.quality <= 1.0
        assert 0.015 < _opening_m(g, 0.5 - 0.012) <= MAX_OPENING_M + 1e-9
    assert [g.quality for g in grasps] == sorted((g.quality for g in grasps), reverse=True)
    # the best grasp is near the middle of the bar (centre of mass)
    assert math.hypot(best.center_xy[0] - 330.0, best.center_xy[1] - 250.0) < 40.0


def test_knife_like_blade() -> None:
    """8 mm wide, 4 mm tall: only the narrow axis fits, and the table leaves room to pinch."""
    scene = bar_scene(angle_deg=-20.0, width_m=0.008, length_m=0.2, height_m=0.004)
    grasps = sample_antipodal_grasps(scene.depth, scene.masks[0], scene.intrinsics)
    assert grasps
    assert math.degrees(angle_difference(grasps[0].angle_rad, math.radians(70.0))) < 10.0


def test_box_is_grasped_across_its_narrow_side() -> None:
    scene = table_scene([Box((320.0, 240.0), 10.0, 0.12, 0.05, 0.06)])
    grasps = sample_antipodal_grasps(scene.depth, scene.masks[0], scene.intrinsics)
    assert grasps
    for g in grasps:
        assert math.degrees(angle_difference(g.angle_rad, math.radians(100.0))) < 20.0


def test_too_wide_object_has_no_grasp() -> None:
    scene = table_scene([Box((320.0, 240.0), 0.0, 0.12, 0.11, 0.05)])
    assert sample_antipodal_grasps(scene.depth, scene.masks[0], scene.intrinsics) == []


def _bar_between_walls(wall_offset_m: float) -> tuple[np.ndarray, np.ndarray, float]:
    """A 15 mm bar with 20 mm-wide, 5 cm-tall walls centred ``wall_offset_m`` to each side."""
    px_per_m = 615.0 / 0.5
    bar = Box((320.0, 240.0), 0.0, 0.15, 0.015, 0.01)
    walls = [
        Box((320.0, 240.0 + s * wall_offset_m * px_per_m), 0.0, 0.3, 0.02, 0.05) for s in (-1, 1)
    ]
    scene = table_scene([bar, *walls])
    return scene.depth, scene.masks[0], 0.5 - 0.01


def test_blocked_sides_have_no_grasp() -> None:
    """Walls 12.5 mm from the bar: less than a finger (10 mm) plus the 5 mm minimum clearance."""
    depth, mask, _ = _bar_between_walls(0.03)
    intr = bar_scene().intrinsics
    assert sample_antipodal_grasps(depth, mask, intr) == []
    free = table_scene([Box((320.0, 240.0), 0.0, 0.15, 0.015, 0.01)])
    assert sample_antipodal_grasps(free.depth, free.masks[0], free.intrinsics)


def test_narrow_gap_uses_the_tight_opening() -> None:
    """Walls 17.5 mm away: no room for the preferred 15 mm clearance, enough for 5 mm."""
    depth, mask, z_top = _bar_between_walls(0.035)
    grasps = sample_antipodal_grasps(depth, mask, bar_scene().intrinsics)
    assert grasps
    assert _opening_m(grasps[0], z_top) == pytest.approx(0.015 + 2 * 0.005, abs=2e-3)
    assert math.degrees(angle_difference(grasps[0].angle_rad, math.pi / 2)) < 10.0


def test_mask_free_segmentation_on_tilted_table() -> None:
    scene = table_scene([Box((300.0, 260.0), 45.0, 0.16, 0.015, 0.012)], tilt=(2e-4, -1e-4))
    est = estimate_object_mask(scene.depth)
    truth = scene.masks[0]
    assert (est & truth).sum() / (est | truth).sum() > 0.95
    grasps = sample_antipodal_grasps(scene.depth, None, scene.intrinsics, max_grasps=3)
    assert grasps and all(truth[round(g.center_xy[1]), round(g.center_xy[0])] for g in grasps)


def test_deterministic_and_seeded() -> None:
    scene = bar_scene(angle_deg=15.0)
    a = sample_antipodal_grasps(scene.depth, scene.masks[0], scene.intrinsics)
    b = sample_antipodal_grasps(scene.depth, scene.masks[0], scene.intrinsics)
    assert a == b
    c = sample_antipodal_grasps(
        scene.depth, scene.masks[0], scene.intrinsics, config=AntipodalConfig(seed=1)
    )
    assert math.degrees(angle_difference(c[0].angle_rad, a[0].angle_rad)) < 10.0


def test_predict_grasps_antipodal_backend() -> None:
    scene = bar_scene(angle_deg=60.0)
    depth = scene.depth.copy()
    depth[200:203, :] = np.nan  # a row of sensor holes
    grasps = predict_grasps("antipodal", scene.rgb, depth, scene.masks[0], max_grasps=2)
    assert 1 <= len(grasps) <= 2
    assert math.degrees(angle_difference(grasps[0].angle_rad, math.radians(150.0))) < 10.0
    assert predict_grasps("antipodal", None, depth, np.zeros_like(scene.masks[0])) == []


def _lookup_by_masking(img: np.ndarray, xs: np.ndarray, ys: np.ndarray, fill: float) -> np.ndarray:
    """The replaced ``_lookup``: a boolean mask of the pixels inside, gathered with it."""
    h, w = img.shape
    xi = np.rint(xs).astype(np.intp)
    yi = np.rint(ys).astype(np.intp)
    inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    out = np.full(xs.shape, fill, dtype=np.float64)
    out[inside] = img[yi[inside], xi[inside]]
    return out


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.bool_, np.uint8])
def test_lookup_equals_the_masked_gather(dtype: type) -> None:
    """Why: the sampler's nearest-pixel lookups were most of its time (~1 ms each on [N, S, M, V]
    sample grids, a dozen per region); the faster form (one flat ``take``, inside kept by a
    ``where``) must give the same values: every dtype the sampler reads, coordinates off every
    edge, on the half-pixel rounding boundaries, and not finite."""
    rng = np.random.default_rng(3)
    img = (rng.random((48, 64)) * 3).astype(dtype)
    xs, ys = rng.uniform(-8.0, 72.0, (40, 6, 5)), rng.uniform(-8.0, 56.0, (40, 6, 5))
    xs[0, 0, :4] = [-0.5, -0.51, 63.49, 63.5]
    ys[0, 1, :4] = [-0.5, -0.51, 47.49, 47.5]
    xs[1, 0, 0], ys[1, 0, 1], xs[1, 0, 2] = np.nan, np.inf, -np.inf
    with np.errstate(invalid="ignore"):  # NaN and inf to int: outside, on both sides
        got, want = _lookup(img, xs, ys, -1.0), _lookup_by_masking(img, xs, ys, -1.0)
    assert got.dtype == np.float64 and got.shape == xs.shape
    assert np.array_equal(got, want)
    assert (got == -1.0).any() and (got != -1.0).any()
