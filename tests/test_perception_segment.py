"""Class-agnostic RGB-D segmentation: plane fit, thin objects, and agreement with GT boxes."""

from __future__ import annotations

import numpy as np
import pytest

from craft_e.runtime.grasp.geometry import CameraIntrinsics
from craft_e.runtime.perception.observation import Observation
from craft_e.runtime.perception.plane import fit_plane
from craft_e.runtime.perception.roi import best_box_matches, box_iou, roi_from_mask
from craft_e.runtime.perception.segment import SegmentConfig, segment
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.oracle import gt_rois
from craft_e.runtime.sim.scene import SceneSpec

TABLE_RGB = (168, 140, 108)


def _synthetic_table(height_map: np.ndarray, rgb: np.ndarray) -> Observation:
    """A camera 0.7 m above a table, looking straight down, seeing ``height_map`` (metres)."""
    h, w = height_map.shape
    intrinsics = CameraIntrinsics.realsense_d435(w, h)
    cam_to_world = np.diag([1.0, -1.0, -1.0, 1.0])
    cam_to_world[2, 3] = 0.7
    return Observation(
        rgb=rgb,
        depth=(0.7 - height_map).astype(np.float32),
        intrinsics=intrinsics,
        cam_to_world=cam_to_world,
    )


def test_plane_fit_recovers_a_tilted_plane_despite_clutter() -> None:
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.3, 0.3, (4000, 2))
    normal = np.array([0.1, -0.05, 1.0]) / np.linalg.norm([0.1, -0.05, 1.0])
    z = (0.6 * normal[2] - xy @ normal[:2]) / normal[2] + rng.normal(0, 0.0005, len(xy))
    table = np.column_stack([xy, z])
    clutter = np.column_stack([rng.uniform(-0.3, 0.3, (1500, 2)), rng.uniform(0.3, 0.55, 1500)])
    plane, inliers = fit_plane(np.vstack([table, clutter]))
    assert 0.9 * len(table) <= inliers <= len(table) + 20  # the table, not the clutter
    assert abs(abs(float(plane.normal @ normal)) - 1.0) < 1e-3


def test_preemptive_plane_scoring_keeps_the_plane_of_the_full_count() -> None:
    """Candidates are first counted on a probe and only the 10 best counted on every sample
    (``PlaneFitConfig.preemptive_keep``): on tables with clutter, box tops (a second, smaller
    plane) and noise, with and without subsampling, the plane must be the one the full count
    of all 200 candidates gives."""
    from dataclasses import replace

    from craft_e.runtime.perception.plane import PlaneFitConfig

    rng = np.random.default_rng(3)
    exhaustive = replace(PlaneFitConfig(), preemptive_keep=0)
    for trial in range(12):
        n_table = int(rng.choice([3000, 15000, 40000]))
        xy = rng.uniform(-0.3, 0.3, (n_table, 2))
        tilt = np.array([rng.normal(0, 0.1), rng.normal(0, 0.1), 1.0])
        normal = tilt / np.linalg.norm(tilt)
        z = (0.6 * normal[2] - xy @ normal[:2]) / normal[2] + rng.normal(0, 0.0008, n_table)
        box_top = np.column_stack([rng.uniform(0.0, 0.1, (n_table // 3, 2)), np.full(n_table // 3, 0.45)])
        clutter = np.column_stack([rng.uniform(-0.3, 0.3, (n_table // 4, 2)),
                                   rng.uniform(0.3, 0.55, n_table // 4)])
        holes = np.full((n_table // 20, 3), np.nan)
        points = np.vstack([np.column_stack([xy, z]), box_top, clutter, holes])[rng.permutation(
            n_table + n_table // 3 + n_table // 4 + n_table // 20)]
        fast, fast_inliers = fit_plane(points)
        full, full_inliers = fit_plane(points, exhaustive)
        assert fast_inliers == full_inliers, trial
        assert np.array_equal(fast.normal, full.normal) and fast.offset == full.offset, trial
        assert abs(abs(float(fast.normal @ normal)) - 1.0) < 1e-3  # and it is the table


def test_cached_ransac_draws_are_the_draws_of_a_fresh_generator() -> None:
    """The plane fit reuses its random draws for a point count it has seen (``plane._draws``):
    they must be the integers a generator seeded for this fit would draw (so the plane is the
    one drawing them anew gives), per count, and read-only (a caller cannot corrupt the cache)."""
    from craft_e.runtime.perception.plane import PlaneFitConfig, _draws

    cfg = PlaneFitConfig()
    for count in (50, cfg.max_samples, 76_800, 61_234):
        rng = np.random.default_rng(cfg.seed)
        chosen = None if count <= cfg.max_samples else rng.choice(count, cfg.max_samples, replace=False)
        size = count if chosen is None else cfg.max_samples
        triples = np.array([rng.choice(size, 3, replace=False) for _ in range(cfg.iterations)])
        for _ in range(2):  # drawn, then from the cache
            cached_chosen, cached_triples = _draws(count, cfg.seed, cfg.max_samples, cfg.iterations)
            assert (cached_chosen is None) == (chosen is None)
            assert chosen is None or np.array_equal(cached_chosen, chosen)
            assert np.array_equal(cached_triples, triples)
            assert not cached_triples.flags.writeable
            assert cached_chosen is None or not cached_chosen.flags.writeable


def test_fill_holes_equals_scipy_on_random_masks() -> None:
    """``segment.fill_holes`` replaces ``ndimage.binary_fill_holes`` on padded masks (the ROI
    masks of ``segment``): the same pixels on random blobs, rings and speckle, and an error for
    a mask that touches its border (where the shortcut would not hold)."""
    from scipy import ndimage

    from craft_e.runtime.perception.segment import fill_holes

    rng = np.random.default_rng(5)
    for trial in range(400):
        h, w = (int(v) for v in rng.integers(1, 50, 2))
        mask = np.pad(rng.random((h, w)) < rng.uniform(0.2, 0.95), 1)
        if trial % 3 == 0:  # smoother blobs with real holes, like an opened segmentation mask
            mask = np.pad(ndimage.binary_opening(mask), 1)
        assert np.array_equal(fill_holes(mask), ndimage.binary_fill_holes(mask)), trial
    ring = np.zeros((7, 7), dtype=bool)
    ring[1:6, 1:6] = True
    ring[3, 3] = False
    assert fill_holes(ring)[3, 3]
    with pytest.raises(ValueError, match="background border"):
        fill_holes(np.ones((4, 4), dtype=bool))


def test_colour_cue_recovers_an_object_too_flat_for_the_depth_threshold() -> None:
    height = np.zeros((120, 160))
    rgb = np.broadcast_to(np.array(TABLE_RGB, np.uint8), (120, 160, 3)).copy()
    height[40:60, 20:140] = 0.002  # a 2 mm blade: below the 5 mm height threshold
    rgb[40:60, 20:140] = (200, 200, 210)
    height[80:100, 60:90] = 0.03  # a normal object
    obs = _synthetic_table(height, rgb)

    with_cue = segment(obs, SegmentConfig(min_area=50)).rois
    depth_only = segment(obs, SegmentConfig(min_area=50, colour_cue=False)).rois
    blade = (20, 40, 120, 20)
    assert max(box_iou(blade, r.box_xywh) for r in with_cue) > 0.9
    assert max((box_iou(blade, r.box_xywh) for r in depth_only), default=0.0) < 0.1
    assert len(with_cue) == 2 and len(depth_only) == 1


def test_roi_geometry() -> None:
    mask = np.zeros((10, 12), dtype=bool)
    mask[2:5, 3:9] = True
    roi = roi_from_mask(mask, label=7)
    assert roi.box_xywh == (3, 2, 6, 3)
    assert roi.area == 18 and roi.label == 7
    assert roi.centroid == pytest.approx((5.5, 3.0))
    assert box_iou((0, 0, 10, 10), (5, 0, 10, 10)) == pytest.approx(50 / 150)
    with pytest.raises(ValueError, match="empty"):
        roi_from_mask(np.zeros((3, 3), dtype=bool))


def test_predicted_rois_match_ground_truth_boxes_including_thin_tools() -> None:
    spec = SceneSpec(
        verb="cut",
        target="knife",
        distractors=("flat_screwdriver", "scissors", "a_cups", "glue_1"),
        seed=11,
    )
    with SimEnv() as env:
        scene = env.reset(spec)
        obs = env.capture()
        assert obs.seg is not None
        assert not np.any(obs.seg == env.robot.body_id), "the arm at home must be out of view"
        assert not np.any(obs.seg == scene.drop_marker_id), "the drop-zone marker is in view"
    reference = gt_rois(obs, scene)
    assert len(reference) == 5, "every object should be visible to the camera"
    predicted = segment(obs).rois
    ious = dict(
        zip(
            [scene.body_assets[r.label] for r in reference if r.label is not None],
            best_box_matches(predicted, reference),
            strict=True,
        )
    )
    assert ious["knife"] >= 0.5, ious
    assert ious["flat_screwdriver"] >= 0.5, ious
    assert sum(iou >= 0.5 for iou in ious.values()) >= 4, ious
    assert len(predicted) <= len(reference) + 1, "spurious ROIs on an empty table"


@pytest.mark.parametrize("size", [(60, 80), (200, 260)])  # all points sampled; a 20k subsample
def test_plane_fit_of_an_image_view_equals_the_fit_of_its_finite_rows(size: tuple[int, int]) -> None:
    """``fit_plane`` takes a strided image view without copying it and gathers only the sampled
    points: the plane and inlier count are those of the finite rows passed as a list (the form
    that gathered every finite point first), bit for bit."""
    rng = np.random.default_rng(size[0])
    h, w = size
    image = np.empty((2 * h, 2 * w, 3))
    image[..., 0], image[..., 1] = rng.uniform(-0.3, 0.3, (2, 2 * h, 2 * w))
    image[..., 2] = 0.6 + 0.05 * image[..., 0] + rng.normal(0, 0.0008, (2 * h, 2 * w))
    image[rng.random((2 * h, 2 * w)) < 0.2] = 0.45  # clutter above the table
    image[rng.random((2 * h, 2 * w)) < 0.1, rng.integers(0, 3)] = np.nan  # no depth
    view = image[::2, ::2]
    rows = view.reshape(-1, 3)
    finite_rows = rows[np.isfinite(rows).all(axis=1)]
    fits = [fit_plane(view), fit_plane(rows), fit_plane(finite_rows)]
    for plane, inliers in fits[1:]:
        assert inliers == fits[0][1]
        assert np.array_equal(plane.normal, fits[0][0].normal) and plane.offset == fits[0][0].offset
