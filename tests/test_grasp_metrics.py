"""The Cornell grasp-rectangle metric, on analytic cases and on the Chu et al. annotations."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from craft_e.paths import shared_dir
from craft_e.runtime.grasp.geometry import Grasp2D
from craft_e.runtime.grasp.metrics import (
    angle_difference,
    grasp_success,
    load_cornell_rectangles,
    max_iou,
    rect_corners,
    rectangle_angle,
    rectangle_iou,
    success_rate,
)


def _annotation_dir() -> Path:
    folder = shared_dir() / "data" / "grasp_multiobject" / "annotations"
    if not folder.is_dir():
        pytest.fail(f"annotations not found at {folder}; set CRAFT_SHARED to the shared folder")
    return folder


def _square(cx: float, cy: float, side: float, angle: float = 0.0) -> np.ndarray:
    return rect_corners((cx, cy), angle, side, side)


def test_iou_analytic_cases() -> None:
    a = _square(0, 0, 2)
    assert rectangle_iou(a, a) == pytest.approx(1.0)
    assert rectangle_iou(a, _square(1, 0, 2)) == pytest.approx(1 / 3)  # half overlap: 2/(4+4-2)
    assert rectangle_iou(a, _square(5, 0, 2)) == 0.0
    assert rectangle_iou(a, _square(0, 0, 1)) == pytest.approx(0.25)  # containment
    # a square and its 45° copy share a regular octagon of area 8(√2-1)
    octagon = 8 * (math.sqrt(2) - 1)
    assert rectangle_iou(a, _square(0, 0, 2, math.pi / 4)) == pytest.approx(octagon / (8 - octagon))
    # corner order (clockwise or not) does not matter
    assert rectangle_iou(a[::-1], _square(1, 0, 2)) == pytest.approx(1 / 3)


def test_angle_difference_is_modulo_pi() -> None:
    assert angle_difference(math.radians(89), math.radians(-89)) == pytest.approx(math.radians(2))
    assert angle_difference(0.0, math.pi) == pytest.approx(0.0, abs=1e-12)
    assert angle_difference(0.0, math.radians(45)) == pytest.approx(math.radians(45))


def test_grasp2d_corners_round_trip() -> None:
    g = Grasp2D((100.0, 50.0), math.radians(-35.0), 40.0, 20.0, 0.7)
    back = Grasp2D.from_corners(g.corners(), quality=0.7)
    assert back.center_xy == pytest.approx(g.center_xy)
    assert back.angle_rad == pytest.approx(g.angle_rad)
    assert (back.width_px, back.length_px) == pytest.approx((40.0, 20.0))
    assert rectangle_angle(g) == pytest.approx(rectangle_angle(g.corners()))
    # p0→p1 runs along the closing axis: for angle 0 it points to +x
    c = Grasp2D((0.0, 0.0), 0.0, 10.0, 4.0, 1.0).corners()
    assert (c[1] - c[0]).tolist() == pytest.approx([10.0, 0.0])


def test_all_annotation_files_parse() -> None:
    files = sorted(_annotation_dir().glob("*_annotations.txt"))
    assert len(files) == 96
    counts = []
    for path in files:
        rects = load_cornell_rectangles(path)
        assert rects.ndim == 3 and rects.shape[1:] == (4, 2), path
        assert len(rects) > 0, f"{path.name}: no rectangles"
        assert np.isfinite(rects).all()
        counts.append(len(rects))
    assert sum(counts) > 96


def test_ground_truth_rectangles_match_themselves_not_rotated_copies() -> None:
    for path in sorted(_annotation_dir().glob("*_annotations.txt"))[:12]:
        rects = load_cornell_rectangles(path)
        for r in rects:
            g = Grasp2D.from_corners(r)
            assert g.width_px > 0 and g.length_px > 0
            assert grasp_success(r, [r])
            assert grasp_success(g, [r])  # same rectangle through (centre, angle, w, l)
            rotated = Grasp2D(g.center_xy, g.angle_rad + math.pi / 4, g.width_px, g.length_px, 1)
            assert not grasp_success(rotated, [r])  # IoU is high, the angle is 45° off
            flipped = Grasp2D(g.center_xy, g.angle_rad + math.pi, g.width_px, g.length_px, 1)
            assert grasp_success(flipped, [r])  # a parallel gripper is symmetric


def test_shifted_copies_pass_or_fail_by_iou() -> None:
    path = _annotation_dir() / "rgb_0000_annotations.txt"
    r = load_cornell_rectangles(path)[0]
    g = Grasp2D.from_corners(r)
    ax, ay = g.axis_xy
    small = r + 0.1 * g.width_px * np.array([ax, ay])  # 10 % along the axis: IoU ≈ 0.82
    assert rectangle_iou(small, r) == pytest.approx(0.9 / 1.1)
    assert grasp_success(small, [r])
    large = r + 0.7 * g.width_px * np.array([ax, ay])  # 70 %: IoU = 0.3/1.7 ≈ 0.18
    assert rectangle_iou(large, r) == pytest.approx(0.3 / 1.7)
    assert not grasp_success(large, [r])
    # any one ground-truth match suffices
    assert grasp_success(large, [r, large])
    assert max_iou(large, [r, large]) == pytest.approx(1.0)


def test_angle_threshold_is_thirty_degrees() -> None:
    r = rect_corners((0.0, 0.0), 0.0, 40.0, 20.0)
    assert grasp_success(rect_corners((0.0, 0.0), math.radians(29.0), 40.0, 20.0), [r])
    assert not grasp_success(rect_corners((0.0, 0.0), math.radians(31.0), 40.0, 20.0), [r])


def test_success_rate_counts_missing_predictions_as_wrong() -> None:
    r = rect_corners((0.0, 0.0), 0.0, 40.0, 20.0)
    assert success_rate([r, None], [[r], [r]]) == 0.5


def test_malformed_annotation_names_file_and_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("1 2\n3 4\n5\n", encoding="utf-8")
    with pytest.raises(ValueError, match=r"bad\.txt:3"):
        load_cornell_rectangles(bad)
    short = tmp_path / "short.txt"
    short.write_text("1 2\n3 4\n5 6\n", encoding="utf-8")
    with pytest.raises(ValueError, match="multiple of 4"):
        load_cornell_rectangles(short)
    nan = tmp_path / "nan.txt"
    nan.write_text("NaN NaN\n0 0\n1 0\n1 1\n0 0\n2 0\n2 1\n0 1\n", encoding="utf-8")
    assert len(load_cornell_rectangles(nan)) == 1
