"""Moving a blocked grasp along its object (``sim.relocate``, ``--relocate``).

Why: in the README demo (`cut`, seed 0) every network grasp of the knife closes towards a tall
cracker box, and the Franka hand comes to rest on the box 14 cm above the knife. These tests pin
the search on a synthetic height map with a known answer, and check on the demo scene itself that
the moved grasp is clear and that the pick then succeeds in physics.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from craft_e.runtime.grasp.geometry import TopDownGrasp
from craft_e.runtime.sim.clearance import ClearanceConfig, HeightMap, hand_hits
from craft_e.runtime.sim.fingers import FingerGeometry, SurfacePoints, finger_check
from craft_e.runtime.sim.hands import PANDA
from craft_e.runtime.sim.relocate import RelocateConfig, nudged, relocate_if_blocked, relocations

FloatArray = npt.NDArray[np.float64]
CFG = ClearanceConfig()
FINGERS = FingerGeometry()
KNIFE_TOP = 0.015


def block(x0: float, x1: float, y0: float, y1: float, z: float, step: float = 0.002) -> FloatArray:
    """Top surface ``[n, 3]`` of an axis-aligned block."""
    xs, ys = np.arange(x0, x1 + 1e-9, step), np.arange(y0, y1 + 1e-9, step)
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)])


KNIFE = block(-0.008, 0.008, -0.10, 0.10, KNIFE_TOP)  # a knife along y, 20 cm long


def tip_z(g: TopDownGrasp) -> float:
    return float(g.position[2]) - 0.012  # finger tips 1.2 cm into the object from its top


def problems(g: TopDownGrasp, h: HeightMap) -> tuple[str | None, str | None]:
    """``pick_problems`` of a hand that reaches everything: only the hand's clearance counts."""
    tcp = np.asarray(g.position) + np.array([0.0, 0.0, 0.0026])
    why = hand_hits(tcp, g.yaw, PANDA.clearance_boxes, h, CFG)
    return None, None if why is None else f"approach blocked: {why}"


def grasp_at(y: float, yaw: float = 0.0) -> TopDownGrasp:
    return TopDownGrasp(np.array([0.0, y, KNIFE_TOP]), yaw, 0.03)


def test_relocations_turn_first_then_slide_along_the_object_nearest_first_and_stay_on_it() -> None:
    spots = list(relocations(grasp_at(0.06), KNIFE, RelocateConfig()))
    yaws = [round(math.degrees(s.yaw)) for s in spots[:4]]
    assert yaws == [15, -15, 30, -30] and all(np.allclose(s.position, [0, 0.06, KNIFE_TOP]) for s in spots[:4])
    ys = [round(float(s.position[1]), 3) for s in spots[4:]]
    # closing along x, so "along the object" is y: +2, -2, +4, -4 cm...; 0.06 + 0.06 is off the knife
    assert ys[:5] == [0.08] * 5 and ys[5:10] == [0.04] * 5 and 0.12 not in ys
    assert all(abs(float(s.position[0])) < 1e-9 and s.position[2] == KNIFE_TOP for s in spots)


def test_a_slide_that_reaches_the_objects_edge_is_not_a_spot() -> None:
    """A slid centre needs object points on both sides along the slide (``RelocateConfig.interior``):
    on a 4.4 cm ball a 2 cm slide from its centre ends 2 mm from the rim, where the fingers would
    close on a sliver (sim-val's spin/racquetball/0 closed on nothing); the knife's tip is such an
    edge too, its middle is not."""
    rng = np.random.default_rng(0)
    disc = rng.uniform(-0.022, 0.022, (4000, 2))
    disc = disc[np.hypot(disc[:, 0], disc[:, 1]) <= 0.022]
    ball = np.column_stack([disc, np.full(len(disc), 0.05)])  # its top, seen from above
    centre = TopDownGrasp(np.array([0.0, 0.0, 0.05]), 0.0, 0.05)
    slid = [s for s in relocations(centre, ball, RelocateConfig()) if float(np.hypot(*s.position[:2])) > 0]
    assert slid == []  # +-2 cm end 2 mm inside the rim; 4 and 6 cm are off the ball
    loose = [s for s in relocations(centre, ball, RelocateConfig(interior=False)) if float(np.hypot(*s.position[:2])) > 0]
    assert {round(float(s.position[1]), 3) for s in loose} == {0.02, -0.02}
    # on the knife, the 4 cm slide from y = 0.06 ends on its tip (y = 0.10): dropped; 2 cm is inside
    ys = {round(float(s.position[1]), 3) for s in relocations(grasp_at(0.06), KNIFE, RelocateConfig())}
    assert 0.08 in ys and 0.10 not in ys
    assert 0.10 in {round(float(s.position[1]), 3)
                    for s in relocations(grasp_at(0.06), KNIFE, RelocateConfig(interior=False))}


def test_a_blocked_grasp_moves_to_the_first_clear_spot_and_a_clear_one_stays() -> None:
    box = block(0.05, 0.12, -0.10, -0.04, 0.21)  # a 21 cm box beside the knife's lower half
    heights = HeightMap(box, CFG.cell, 0.0)
    blocked = grasp_at(-0.05)  # closes along x, into the box
    assert problems(blocked, heights)[1] is not None
    result = relocate_if_blocked(blocked, [], KNIFE, heights, problems, tip_z, FINGERS, RelocateConfig())
    assert result.moved and result.detail.startswith("approach blocked")
    assert problems(result.pose, heights) == (None, None)
    assert finger_check(SurfacePoints(KNIFE), result.pose, tip_z(result.pose), FINGERS)[0]
    assert abs(float(result.pose.position[0])) <= 0.008  # still on the knife
    clear = grasp_at(0.06)
    kept = relocate_if_blocked(clear, [], KNIFE, heights, problems, tip_z, FINGERS, RelocateConfig())
    assert kept.pose is clear and not kept.moved and kept.detail == ""


def test_spot_problems_answer_for_the_spots_and_problems_for_the_chosen_grasp() -> None:
    """``spot_problems`` (the staged check, ``pick_problems(approach_first=True)``) is asked about
    every spot tried and never about the chosen grasp, whose blocked-or-clear answer (and the
    message the detail carries) stays the whole plan's; the spot taken is the same."""
    box = block(0.05, 0.12, -0.10, -0.04, 0.21)
    heights = HeightMap(box, CFG.cell, 0.0)
    blocked = grasp_at(-0.05)
    asked: list[TopDownGrasp] = []

    def staged(g: TopDownGrasp, h: HeightMap) -> tuple[str | None, str | None]:
        asked.append(g)
        return problems(g, h)

    plain = relocate_if_blocked(blocked, [], KNIFE, heights, problems, tip_z, FINGERS, RelocateConfig())
    result = relocate_if_blocked(blocked, [], KNIFE, heights, problems, tip_z, FINGERS, RelocateConfig(), staged)
    assert result.moved and result.detail == plain.detail and result.pose.yaw == plain.pose.yaw
    assert np.array_equal(result.pose.position, plain.pose.position)
    assert asked and all(g is not blocked for g in asked) and asked[-1] is result.pose
    asked.clear()
    clear = grasp_at(0.06)
    assert not relocate_if_blocked(clear, [], KNIFE, heights, problems, tip_z, FINGERS, RelocateConfig(), staged).moved
    assert asked == []  # a clear grasp tries no spot


def test_with_no_clear_spot_the_grasp_is_kept_and_the_detail_says_so() -> None:
    wall = block(0.03, 0.12, -0.20, 0.20, 0.21)  # beside the whole knife, closer than the hand reaches
    heights = HeightMap(wall, CFG.cell, 0.0)
    blocked = grasp_at(0.0)
    result = relocate_if_blocked(blocked, [grasp_at(0.05)], KNIFE, heights, problems, tip_z,
                                 FINGERS, RelocateConfig())
    assert result.pose is blocked and not result.moved and result.detail.endswith("kept")


def test_the_next_network_grasp_is_tried_when_the_first_has_no_clear_spot_nearby() -> None:
    box = block(0.05, 0.12, -0.20, 0.02, 0.21)
    heights = HeightMap(box, CFG.cell, 0.0)
    first, second = grasp_at(-0.08), grasp_at(0.09)  # 2-6 cm from the first is still beside the box
    result = relocate_if_blocked(first, [second], KNIFE, heights, problems, tip_z, FINGERS,
                                 RelocateConfig(turns_deg=()))
    assert result.moved and "network grasp #2" in result.detail
    assert float(result.pose.position[1]) > 0.05


def test_nudges_move_along_the_closing_axis_nearest_first_and_stay_on_the_object() -> None:
    """The knife lies along y, the grasp closes along x: nudges go to x = +-1 cm (each also
    turned), and +-2 cm, 1.2 cm from the 1.6 cm knife's nearest points, is off it."""
    spots = list(nudged(grasp_at(0.0), KNIFE, RelocateConfig()))
    xs = [round(float(g.position[0]), 3) for g in spots]
    assert xs == [0.01] * 5 + [-0.01] * 5
    assert [round(math.degrees(g.yaw)) for g in spots[:5]] == [0, 15, -15, 30, -30]
    assert all(abs(float(g.position[1])) < 1e-9 and g.position[2] == KNIFE_TOP for g in spots)
    assert list(nudged(grasp_at(0.0), np.zeros((0, 3)), RelocateConfig())) == []


def test_a_nudge_is_the_last_resort_and_clears_a_hand_that_just_reaches_a_wall() -> None:
    """A wall along the whole knife whose edge the open hand's body reaches by 4 mm: no slide
    along the knife and no turn (turns off here) clears it, a 1 cm nudge away from it does."""
    reach = max(b.y_hi for b in PANDA.clearance_boxes)
    wall = block(reach - 0.004, 0.30, -0.20, 0.20, 0.21)
    heights = HeightMap(wall, CFG.cell, 0.0)
    blocked = grasp_at(0.0)
    assert problems(blocked, heights)[1] is not None
    no_nudge = RelocateConfig(turns_deg=(), nudges=())
    assert not relocate_if_blocked(blocked, [grasp_at(0.05)], KNIFE, heights, problems, tip_z, FINGERS, no_nudge).moved
    result = relocate_if_blocked(blocked, [grasp_at(0.05)], KNIFE, heights, problems, tip_z, FINGERS,
                                 RelocateConfig(turns_deg=()))
    assert result.moved and "network grasp" not in result.detail and "moved 1.0 cm" in result.detail
    assert float(result.pose.position[0]) == pytest.approx(-0.01)
    assert problems(result.pose, heights) == (None, None)


@pytest.mark.parametrize("bad", [{"turns_deg": (90.0,)}, {"shifts": (0.0,)}, {"nudges": (-0.01,)},
                                 {"min_footing_points": 0}])
def test_config_rejects_values_that_make_no_sense(bad: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        RelocateConfig(**bad)  # type: ignore[arg-type]


def test_in_the_demo_scene_both_paths_move_the_blocked_knife_grasp_alike_and_the_pick_succeeds() -> None:
    """The README demo (`cut`, seed 0): the knife's best fitting grasp is blocked by the cracker
    box (``test_clearance.py``). The evaluation's path (``pipeline.relocated_grasp``) and the
    robot's (``choose.relocate_choice``) move it to the same clear spot, and physics picks it."""
    from craft_e.paths import SIM_DEV_LABELS
    from craft_e.runtime.evaluation.sim_eval import (
        default_encoder,
        load_sim_labels,
        make_episode_specs,
    )
    from craft_e.runtime.sim.choose import perceive_for_pick, relocate_choice
    from craft_e.runtime.sim.env import SimEnv
    from craft_e.runtime.sim.episode import Outcome, execute_pick
    from craft_e.runtime.sim.perceive import perceive
    from craft_e.runtime.sim.pipeline import PipelineConfig, relocated_grasp

    spec = next(s for s in make_episode_specs(load_sim_labels(SIM_DEV_LABELS), layouts=1) if s.id == "cut/knife/0")
    config = PipelineConfig()
    assert config.pick.clearance.relocate  # on by default
    encoder = default_encoder(1)
    with SimEnv() as env:
        env.reset(spec.scene)
        env.robot.reset_home()
        obs = env.capture()
        eager = perceive(env, encoder, config, obs)
        knife = eager.target_roi
        assert knife is not None and eager.rois[knife].usable
        chosen = eager.rois[knife].usable[0]
        moved, why = relocated_grasp(env, obs, eager.rois[knife], chosen, config)
        assert why.startswith("approach blocked") and moved.pose is not None and moved.pose is not chosen.pose, why
        assert moved.quality == chosen.quality  # grounding is unaffected
        lazy = perceive_for_pick(env, encoder, config, obs)[knife]
        lazy_chosen = lazy.as_roi("knife").grasps[0]
        lazy_moved, lazy_why = relocate_choice(env, config, obs, lazy, lazy_chosen)
        assert lazy_why == why
        assert isinstance(lazy_moved, type(moved)) and lazy_moved.pose is not None
        np.testing.assert_allclose(lazy_moved.pose.position, moved.pose.position, atol=1e-6)
        assert lazy_moved.pose.yaw == pytest.approx(moved.pose.yaw, abs=1e-6)
        env.robot.reset_home()
        picked = execute_pick(env, moved.pose, env.scene.target.body_id, config.pick)
        assert picked.outcome is Outcome.SUCCESS, picked.detail
