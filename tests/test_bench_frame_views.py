"""The camera poses and counts of ``benchmarks/bench_frame_views.py``.

Why: the benchmark's table reads "tilted 30 degrees" and "not an object"; the poses must be
those angles at the testbed camera's distance from the same point, and a region must count as an
object by the share of its pixels that show one, whichever the box would say.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import load_script

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_frame_views.py"


def test_every_view_looks_at_the_same_point_from_its_angle_and_distance() -> None:
    bench = load_script(SCRIPT)
    target = np.array(bench.TARGET)
    for view in bench.VIEWS:
        offset = np.array(view.eye()) - target
        assert np.linalg.norm(offset) == pytest.approx(view.distance)
        assert math.degrees(math.acos(offset[2] / np.linalg.norm(offset))) == pytest.approx(view.tilt_deg)
    by_name = {v.name: v for v in bench.VIEWS}
    assert by_name["tilted 30 deg, far side"].eye()[0] > target[0]  # beyond the table, away from the arm
    assert by_name["tilted 20 deg, over the arm"].eye()[0] < target[0]
    assert by_name["tilted 45 deg, side"].eye()[1] > 0 and by_name["overhead (the testbed's)"].eye()[2] == 0.70


def test_a_region_is_an_object_when_half_its_pixels_show_one() -> None:
    bench = load_script(SCRIPT)
    seg = np.zeros((4, 4), np.int32)  # 0: the arm
    seg[:2, :] = 5  # an object's body in the top half
    mask = np.zeros((4, 4), bool)
    mask[1:3, :] = True  # half on the object, half on the arm
    assert bench._is_object(mask, seg, {5}, (0, 0, 4, 4))
    mask[1, :2] = False
    assert not bench._is_object(mask, seg, {5}, (0, 0, 4, 4))
    assert bench._is_object(None, seg, {5}, (0, 0, 4, 2))  # no mask: the box's pixels
    summary = bench.summarise([
        {"scene": "a", "detect": True, "chosen_not_object": False, "grasp": True, "regions": 5,
         "regions_not_object": 1, "target_visible": True},
        {"scene": "b", "error": "no table", "target_visible": False}])
    assert summary["detect"] == 1 and summary["errors"] == 1 and summary["regions_mean"] == 5.0
    assert summary["chose_not_object_in"] == [] and summary["target_visible"] == 1
