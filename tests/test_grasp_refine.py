"""Network grasps fitted to the hand (``sim.refine``): turned, or moved onto a vessel's wall.

Why: every ``no_grasp`` episode on the dev scenes was a cup, mug, bottle, pitcher or sponge whose
network grasp closed across a section wider than the hand's 76 mm, while a turn of the same grasp
or one finger inside the rim would fit. Checked on synthetic surfaces with known answers, and on
what the robot's candidate list does with them (``candidates.with_refinements``).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from craft_e.runtime.grasp.geometry import CameraIntrinsics, Grasp2D, TopDownGrasp
from craft_e.runtime.perception.observation import Observation
from craft_e.runtime.sim.candidates import GraspCandidate, tip_height, with_refinements
from craft_e.runtime.sim.episode import PickConfig
from craft_e.runtime.sim.fingers import FingerGeometry, finger_check
from craft_e.runtime.sim.pipeline import PipelineConfig
from craft_e.runtime.sim.refine import RefineConfig, candidates, refine, turns, wall_runs

FloatArray = npt.NDArray[np.float64]
FINGERS = FingerGeometry()
PICK = PickConfig()
TABLE_Z = 0.0


def tip_z_of(pose: TopDownGrasp) -> float:
    return tip_height(pose, PICK, TABLE_Z)


def grid(half_x: float, half_y: float, step: float = 0.002) -> FloatArray:
    """``[n, 2]`` points on a regular grid over a rectangle centred at the origin."""
    xs = np.arange(-half_x, half_x + 1e-9, step)
    ys = np.arange(-half_y, half_y + 1e-9, step)
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def box_surface(long_m: float = 0.10, short_m: float = 0.06, height: float = 0.05) -> FloatArray:
    """Top surface ``[n, 3]`` of a box lying with its long side along x (a sponge, a bottle)."""
    xy = grid(long_m / 2, short_m / 2)
    return np.column_stack([xy, np.full(len(xy), height)])


def cup_surface(outer_r: float = 0.040, wall: float = 0.003, rim_z: float = 0.07,
                floor_z: float = 0.005) -> FloatArray:
    """What a camera above sees of an open cup: the rim ring high, the floor inside low."""
    xy = grid(outer_r, outer_r, 0.0015)
    r = np.hypot(xy[:, 0], xy[:, 1])
    xy = xy[r <= outer_r]
    r = r[r <= outer_r]
    z = np.where(r >= outer_r - wall, rim_z, floor_z)
    return np.column_stack([xy, z])


def pose(x: float, y: float, z: float, yaw_deg: float) -> TopDownGrasp:
    return TopDownGrasp(position=np.array([x, y, z]), yaw=math.radians(yaw_deg), width_m=0.05)


def fits(material: FloatArray, p: TopDownGrasp) -> bool:
    return finger_check(material, p, tip_z_of(p), FINGERS)[0]


def test_turns_smallest_first_each_sign_once() -> None:
    deg = [round(math.degrees(t)) for t in turns(RefineConfig(yaw_step_deg=30.0))]
    assert deg == [0, 30, -30, 60, -60, 90]


@pytest.mark.parametrize("kwargs", [{"yaw_step_deg": 0.0}, {"yaw_step_deg": 50.0, "max_yaw_deg": 40.0},
                                    {"max_yaw_deg": 120.0}, {"max_shift": -0.01}])
def test_config_rejects_impossible_limits(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        RefineConfig(**kwargs)


def test_a_grasp_across_the_long_side_is_turned_about_its_centre() -> None:
    material = box_surface()  # 10 x 6 cm: the long side does not fit 7.6 cm, the short one does
    across_long = pose(0.0, 0.0, 0.05, 0.0)
    assert not fits(material, across_long)
    better = refine(across_long, material, tip_z_of, FINGERS, RefineConfig())
    assert better is not None and fits(material, better)
    np.testing.assert_allclose(better.position, across_long.position)  # same spot, only turned
    assert abs(abs(math.degrees(better.yaw)) - 90.0) <= 30.0  # closes across the short side


def test_a_cup_too_wide_for_the_hand_is_taken_by_its_wall() -> None:
    material = cup_surface()  # 8 cm across: no turn fits
    centre = pose(0.0, 0.0, 0.005, 20.0)  # the network's grasp in the middle of the cup
    assert not fits(material, centre)
    assert all(not fits(material, c) for c in candidates(centre, material, tip_z_of, FINGERS, RefineConfig())
               if np.allclose(c.position[:2], 0.0))
    better = refine(centre, material, tip_z_of, FINGERS, RefineConfig())
    assert better is not None and fits(material, better)
    radius = float(np.hypot(better.position[0], better.position[1]))
    assert 0.036 <= radius <= 0.041  # on the wall (outer radius 4 cm, 3 mm thick)
    assert better.position[2] == pytest.approx(0.07)  # taken from the rim's top
    # the hand closes radially, across the wall: its axis points at the cup's centre
    radial = math.atan2(better.position[1], better.position[0])
    assert abs(math.sin(radial - better.yaw)) < 0.2


def test_wall_runs_split_a_cup_into_its_two_walls() -> None:
    runs = wall_runs(cup_surface(), np.zeros(2), 0.0, tip_z_of, FINGERS)
    assert len(runs) == 2
    (lo1, hi1, top1), (lo2, hi2, top2) = runs
    assert hi1 - lo1 < 0.01 and hi2 - lo2 < 0.01 and top1 == top2 == pytest.approx(0.07)
    assert lo1 < -0.035 and hi2 > 0.035


def test_a_solid_object_wider_than_the_hand_gets_no_refinement() -> None:
    xy = grid(0.05, 0.05)
    disk = xy[np.hypot(xy[:, 0], xy[:, 1]) <= 0.05]
    material = np.column_stack([disk, np.full(len(disk), 0.06)])  # a 10 cm can, closed
    assert refine(pose(0.0, 0.0, 0.06, 0.0), material, tip_z_of, FINGERS, RefineConfig()) is None


def test_disabled_refinement_changes_nothing() -> None:
    material = box_surface()
    assert refine(pose(0.0, 0.0, 0.05, 0.0), material, tip_z_of, FINGERS, RefineConfig(enabled=False)) is None


def _candidate(p: TopDownGrasp, quality: float) -> GraspCandidate:
    rect = Grasp2D(center_xy=(320.0, 240.0), angle_rad=0.0, width_px=40.0, length_px=20.0, quality=quality)
    return GraspCandidate(rect, p)


def test_with_refinements_adds_a_fitting_grasp_right_after_the_one_it_fixes() -> None:
    intr = CameraIntrinsics.realsense_d435()  # a camera 0.7 m straight above; only its model is used
    cam_to_world = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, 0.7], [0, 0, 0, 1.0]])
    obs = Observation(np.zeros((intr.height, intr.width, 3), np.uint8),
                      np.full((intr.height, intr.width), 0.7, np.float32), intr, cam_to_world)
    material = box_surface()
    bad, good = pose(0.0, 0.0, 0.05, 0.0), pose(0.0, 0.0, 0.05, 90.0)
    config = PipelineConfig()
    out = with_refinements([_candidate(bad, 0.9), _candidate(good, 0.7)], material, obs, TABLE_Z, config)
    assert len(out) == 3
    assert out[0].pose is bad and out[2].pose is good  # the originals keep their order
    assert out[1].pose is not None and fits(material, out[1].pose)
    assert out[1].quality == pytest.approx(0.9)  # the network's judgement of the spot is kept
    # a grasp that fits already is left alone, and switching refinement off keeps the raw list
    assert len(with_refinements([_candidate(good, 0.7)], material, obs, TABLE_Z, config)) == 1
    off = PipelineConfig(refine=RefineConfig(enabled=False))
    assert [c.pose for c in with_refinements([_candidate(bad, 0.9)], material, obs, TABLE_Z, off)] == [bad]
