"""The carry keeps a held object clear of the arm (``PickConfig.carry_check``,
``episode.carry_yaws``, ``surface.object_points``)."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pybullet as p
import pytest
from conftest import episode_spec

from craft_e.runtime.perception.roi import BoolMask
from craft_e.runtime.sim.episode import PickConfig, carry_yaws
from craft_e.runtime.sim.surface import HELD_POINTS, RaisedPoints, object_points


def test_the_carry_tries_yaw_0_then_the_wrist_still_then_a_quarter_turn() -> None:
    grasp_yaw = 0.3
    # a grasp straight ahead of the base (+x), the zone to its right (-y): the arm turns -90°
    yaws = carry_yaws((0.5, 0.0), grasp_yaw, (0.0, -0.4))
    assert yaws == pytest.approx([0.0, grasp_yaw - math.pi / 2, math.pi / 2])
    # the wrist still: the closing axis keeps its angle to the line from the base to the hand
    grasp_xy, zone = (0.3, 0.25), (0.02, -0.40)
    still = carry_yaws(grasp_xy, grasp_yaw, zone)[1]
    assert still - math.atan2(zone[1], zone[0]) == pytest.approx(grasp_yaw - math.atan2(grasp_xy[1], grasp_xy[0]))
    # measured from the robot's base, wherever it stands
    moved = carry_yaws((1.5, 1.0), grasp_yaw, (1.0, 0.6), base_xy=(1.0, 1.0))
    assert moved[1] == pytest.approx(grasp_yaw - math.pi / 2)


def _raised(points: np.ndarray, mask: BoolMask) -> RaisedPoints:
    pixels = np.flatnonzero(mask)
    return RaisedPoints(mask, pixels, points)


def test_an_objects_points_are_its_raised_points_evenly_strided_and_capped() -> None:
    mask = np.zeros((40, 40), dtype=bool)
    mask[:30, :30] = True  # 900 raised pixels
    points = np.arange(900 * 3, dtype=np.float64).reshape(900, 3)
    raised = _raised(points, mask)
    region = np.zeros_like(mask)
    region[:2, :5] = True  # 10 of them: every one
    np.testing.assert_array_equal(object_points(raised, region), points[[0, 1, 2, 3, 4, 30, 31, 32, 33, 34]])
    whole = object_points(raised, mask)
    assert whole is not None and len(whole) <= HELD_POINTS
    np.testing.assert_array_equal(whole, points[:: math.ceil(900 / HELD_POINTS)])
    assert object_points(raised, np.zeros_like(mask)) is None
    with pytest.raises(ValueError, match="limit must be >= 1, got 0"):
        object_points(raised, mask, limit=0)


def test_a_negative_carry_margin_is_named() -> None:
    with pytest.raises(ValueError, match=re.escape("PickConfig.carry_margin -0.01 m must be >= 0")):
        PickConfig(carry_margin=-0.01)


def test_a_long_spatula_is_carried_clear_of_the_upper_arm() -> None:
    """sim-dev's ``stir/spatula/2`` at ``--seed 2``: the 30 cm spatula, carried at yaw 0, swings
    into the upper arm (``Link2``) on the way to the zone and falls out of the hand. With the
    check the carry turns (yaw 0 and the wrist still both touch, a quarter turn is clear) and the
    spatula lands in the zone. Same grasp, same scene, both ways."""
    from craft_e.paths import SIM_DEV_LABELS
    from craft_e.runtime.evaluation.sim_eval import default_encoder
    from craft_e.runtime.sim.env import SimEnv
    from craft_e.runtime.sim.episode import Outcome, execute_pick
    from craft_e.runtime.sim.perceive import perceive
    from craft_e.runtime.sim.pipeline import PipelineConfig, relocated_grasp
    from craft_e.runtime.sim.surface import object_centre

    spec = episode_spec(SIM_DEV_LABELS, "stir/spatula/2", seed=2)
    config = PipelineConfig()
    with SimEnv() as env:
        env.reset(spec.scene)
        env.robot.reset_home()
        perception = perceive(env, default_encoder(1), config)
        spatula = perception.target_roi
        assert spatula is not None and perception.rois[spatula].usable
        roi = perception.rois[spatula]
        start = p.saveState(physicsClientId=env.client)
        grasp, _ = relocated_grasp(env, perception.obs, roi, roi.usable[0], config)
        assert grasp.pose is not None
        centre = object_centre(perception.raised, roi.roi.mask)
        seen = object_points(perception.raised, roi.roi.mask)
        assert seen is not None
        outcomes = {}
        for check in (False, True):
            p.restoreState(stateId=start, physicsClientId=env.client)
            pick = dataclasses.replace(config.pick, carry_check=check)
            outcomes[check] = execute_pick(env, grasp.pose, perception.target_body, pick, centre, None, seen)
    assert outcomes[False].outcome is Outcome.SLIP_DURING_TRANSPORT, outcomes[False].detail
    assert outcomes[True].outcome is Outcome.SUCCESS, outcomes[True].detail
