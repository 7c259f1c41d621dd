"""One grasp-network pass per frame, per-ROI peaks from the shared maps (issue 10, item 4).

Why these tests: the pipeline no longer runs the network once per ROI. Each ROI's grasps must be
exactly the peaks of the shared quality map inside that ROI's mask (its best grasp is the
masked argmax), no ROI may take a peak from its neighbour, and a frame with a single ROI must
give what the per-ROI path gave.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from craft_e.runtime.grasp.postprocess import ProcessedMaps, detect_grasps
from craft_e.runtime.grasp.predict import (
    PEAK_SPACING_PX,
    CropWindow,
    FrameMaps,
    frame_window,
    predict_frame,
    predict_grasps,
    predict_grasps_rois,
)
from craft_e.runtime.grasp.synthetic import Box, bar_scene, table_scene


def _blob(shape: tuple[int, int], centre: tuple[float, float], peak: float, sigma: float) -> np.ndarray:
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    return peak * np.exp(-((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) / (2 * sigma**2))


def _frame() -> tuple[FrameMaps, list[np.ndarray]]:
    """Shared maps over a 448 px crop (2 image px per network px) and two image-space ROIs.

    The strong blob (0.9) lies in ROI A, next to ROI B; B's own best value is weaker (0.5), so a
    peak leaking across the boundary would show up as a wrong centre for B.
    """
    rng = np.random.default_rng(0)
    s = 224
    q = _blob((s, s), (80, 100), 0.9, 8.0) + _blob((s, s), (140, 110), 0.5, 6.0)
    q += 0.02 * rng.random((s, s))  # no ties: the argmax is unique
    maps = ProcessedMaps(q.astype(np.float32), np.full((s, s), 0.3, np.float32), np.full((s, s), 20.0, np.float32))
    window = CropWindow(x0=96, y0=16, side=448, out_size=s)
    frame = FrameMaps(maps, window, np.ones((s, s), dtype=bool))
    a = np.zeros((480, 640), dtype=bool)
    b = np.zeros((480, 640), dtype=bool)
    # image rows/columns of network rows 70..129 / columns 50..109 (A) and 80..139 / 115..169 (B)
    a[16 + 2 * 70 : 16 + 2 * 130, 96 + 2 * 50 : 96 + 2 * 110] = True
    b[16 + 2 * 80 : 16 + 2 * 140, 96 + 2 * 115 : 96 + 2 * 170] = True
    return frame, [a, b]


def test_roi_peak_is_the_argmax_of_the_shared_map_inside_the_mask() -> None:
    frame, masks = _frame()
    for mask in masks:
        region = frame.window.resample_mask(mask[frame.window.slices])  # [S, S]
        masked = np.where(region, frame.maps.quality, -np.inf)
        row, col = np.unravel_index(int(np.argmax(masked)), masked.shape)
        best = frame.grasps_in(mask, max_grasps=3)[0]
        expected = frame.window.to_image(detect_grasps(frame.maps, 1, frame.min_distance, mask=region)[0])
        assert best == expected
        # the masked argmax, mapped back to image pixels
        s = frame.window.scale
        assert best.center_xy == (frame.window.x0 + s * col + 0.5 * s - 0.5,
                                  frame.window.y0 + s * row + 0.5 * s - 0.5)
        assert best.quality == pytest.approx(float(frame.maps.quality[row, col]))


def test_rois_do_not_take_each_others_peaks() -> None:
    frame, (a, b) = _frame()
    for mask in (a, b):
        for g in frame.grasps_in(mask, max_grasps=5):
            assert mask[round(g.center_xy[1]), round(g.center_xy[0])]
    assert frame.grasps_in(a, 1)[0].quality > 0.85  # A owns the strong blob
    assert frame.grasps_in(b, 1)[0].quality < 0.6  # B's best is its own, weaker blob


def test_peak_spacing_is_kept_in_image_pixels() -> None:
    frame, _ = _frame()
    assert frame.window.scale == 2.0
    assert frame.min_distance == PEAK_SPACING_PX // 2


def test_empty_and_missing_masks() -> None:
    frame, _ = _frame()
    assert frame.grasps_in(np.zeros((480, 640), dtype=bool)) == []
    scene = bar_scene()
    assert predict_grasps_rois("grconvnet", scene.rgb, scene.depth, [np.zeros_like(scene.masks[0])]) == [[]]
    with pytest.raises(ValueError, match="backend"):
        predict_grasps_rois("graspnet", scene.rgb, scene.depth, scene.masks)


@pytest.mark.parametrize("name", ["grconvnet", "ggcnn"])
def test_single_roi_frame_pass_equals_the_per_roi_pass(name: str) -> None:
    scene = bar_scene(angle_deg=60.0, width_m=0.03, length_m=0.12, height_m=0.03)
    mask = scene.masks[0]
    # resized to the network's size, one ROI gets exactly the per-ROI crop: identical grasps
    square = predict_frame(name, scene.rgb, scene.depth, [mask], native=False)
    assert square.window.scale == 1.0  # a small ROI: the 224 px crop at 1:1, spacing 20 px
    rois = predict_grasps_rois(name, scene.rgb, scene.depth, [mask], max_grasps=3, min_quality=0.05, native=False)
    per_roi = predict_grasps(name, scene.rgb, scene.depth, mask, max_grasps=3, min_quality=0.05)
    assert rois == [per_roi] and per_roi
    # at native scale (the default) the window differs a little: the best grasp barely moves
    best = predict_grasps_rois(name, scene.rgb, scene.depth, [mask], max_grasps=3, min_quality=0.05)[0][0]
    assert math.hypot(best.center_xy[0] - per_roi[0].center_xy[0], best.center_xy[1] - per_roi[0].center_xy[1]) < 6.0
    assert abs(math.sin(best.angle_rad - per_roi[0].angle_rad)) < math.sin(math.radians(15.0))


def test_frame_window_holds_every_roi_at_native_scale() -> None:
    mask = np.zeros((480, 640), dtype=bool)
    mask[100:160, 30:90] = True
    mask[300:420, 500:630] = True
    win = frame_window((480, 640), mask)
    assert win.scale == 1.0 and win.width % 12 == 0 and win.height % 12 == 0
    assert win.x0 >= 0 and win.x0 + win.width <= 640 and win.y0 >= 0 and win.y0 + win.height <= 480
    rows, cols = win.slices
    assert mask[rows, cols].sum() == mask.sum()  # nothing cut off
    small = np.zeros((480, 640), dtype=bool)
    small[200:210, 300:310] = True
    assert frame_window((480, 640), small).width >= 224  # the networks' own input size at least


def test_one_pass_serves_several_rois() -> None:
    scene = table_scene([Box((200.0, 200.0), 30.0, 0.12, 0.03, 0.03), Box((430.0, 280.0), 100.0, 0.12, 0.03, 0.03)])
    per_roi = predict_grasps_rois("grconvnet", scene.rgb, scene.depth, scene.masks, max_grasps=3, min_quality=0.05)
    frame = predict_frame("grconvnet", scene.rgb, scene.depth, scene.masks)
    assert len(per_roi) == 2
    for mask, grasps in zip(scene.masks, per_roi, strict=True):
        assert grasps and grasps == frame.grasps_in(mask, 3, 0.05)
        assert all(mask[round(g.center_xy[1]), round(g.center_xy[0])] for g in grasps)


def test_peaks_in_a_mask_equal_the_peaks_of_the_zeroed_map() -> None:
    """``find_peaks_in_mask`` works on the mask's box plus a margin only; its peaks must be the
    full computation's exactly (order included), also for masks at the map's border, thin masks,
    masks in several pieces and plateaus of equal values."""
    from scipy import ndimage

    from craft_e.runtime.grasp.postprocess import find_peaks, find_peaks_in_mask

    rng = np.random.default_rng(7)
    compared = found = 0
    for trial in range(300):
        shape = (int(rng.integers(40, 160)), int(rng.integers(40, 160)))
        image = ndimage.gaussian_filter(rng.random(shape), float(rng.uniform(1.0, 6.0)))
        image = (image - image.min()) / (image.max() - image.min() + 1e-12)
        if trial % 5 == 0:
            image = np.round(image * 4) / 4  # plateaus: equal neighbours to thin
        mask = np.zeros(shape, dtype=bool)
        for _ in range(int(rng.integers(1, 3))):
            r, c = int(rng.integers(0, shape[0])), int(rng.integers(0, shape[1]))
            h, w = int(rng.integers(1, shape[0] // 2 + 2)), int(rng.integers(1, shape[1] // 2 + 2))
            mask[max(r - h, 0): r + h, max(c - w, 0): c + w] = True
        min_distance = int(rng.choice([1, 3, 8, 20]))
        threshold = float(rng.uniform(0.0, 0.6))
        for border in (True, False):
            full = find_peaks(np.where(mask, image, 0.0), min_distance, threshold, num_peaks=10,
                              exclude_border=border)
            cropped = find_peaks_in_mask(image, mask, min_distance, threshold, num_peaks=10,
                                         exclude_border=border)
            assert np.array_equal(full, cropped), (trial, border)
            compared += 1
            found += len(full)
    assert compared == 600 and found > 300
    assert find_peaks_in_mask(np.ones((10, 10)), np.zeros((10, 10), dtype=bool)).shape == (0, 2)
