"""A grasp leaned about its closing axis: the relocation's last resort (``sim/relocate.py``).

Why: a top-down grasp fixes the wrist's height above the object. Beside a 21 cm block the CR3's
wrist links come down on it, whatever spot of the knife and whatever IK posture
(sim-dev's ``cut/knife/1``). Leaning the hand 20° keeps the pads level on the same closing line and
swings the wrist sideways. These tests pin the orientation, the clearance check of a leaned
hand, where the lean comes in the relocation search, and that physics completes such a pick.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from craft_e.runtime.grasp.geometry import TopDownGrasp
from craft_e.runtime.sim.clearance import ClearanceConfig, HeightMap, first_hit, leaned_first_hit
from craft_e.runtime.sim.fingers import FingerGeometry
from craft_e.runtime.sim.hands import PANDA, hand_spec
from craft_e.runtime.sim.relocate import RelocateConfig, relocate_if_blocked
from craft_e.runtime.sim.robot import (
    TcpPose,
    tool_quat,
    tool_rotation,
    top_down_quat,
    top_down_rotation,
)

FloatArray = npt.NDArray[np.float64]
CFG = ClearanceConfig()
LEAN = math.radians(20.0)


def block(x0: float, x1: float, y0: float, y1: float, z: float, step: float = 0.002) -> FloatArray:
    """Top surface ``[n, 3]`` of an axis-aligned block."""
    xs, ys = np.arange(x0, x1 + 1e-9, step), np.arange(y0, y1 + 1e-9, step)
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)])


@pytest.mark.parametrize("yaw", [0.0, 0.7, -1.2])
def test_a_lean_keeps_the_closing_axis_level_and_tilts_the_approach_by_its_angle(yaw: float) -> None:
    assert tool_quat(yaw) == top_down_quat(yaw)  # no lean: the top-down orientation, bit for bit
    assert tool_rotation(yaw) is top_down_rotation(yaw)
    for lean in (LEAN, -LEAN):
        r = tool_rotation(yaw, lean)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(r[:, 1], top_down_rotation(yaw)[:, 1], atol=1e-12)  # the same closing axis
        assert math.degrees(math.acos(-r[2, 2])) == pytest.approx(20.0)  # the approach 20° off vertical
        assert TcpPose(np.zeros(3), r).lean == pytest.approx(lean)
        # the same hand named with the closing axis the other way round leans the other way
        np.testing.assert_allclose(tool_rotation(yaw + math.pi, -lean)[:, 2], r[:, 2], atol=1e-12)
    assert TcpPose(np.zeros(3), top_down_rotation(yaw)).lean == pytest.approx(0.0, abs=1e-12)


def test_after_a_miss_a_leaned_hand_rises_leaned_and_a_top_down_one_exactly_top_down() -> None:
    from craft_e.runtime.sim.retry import rising_lean

    assert rising_lean(TcpPose(np.zeros(3), tool_rotation(0.4, -LEAN))) == pytest.approx(-LEAN)
    assert rising_lean(TcpPose(np.zeros(3), tool_rotation(0.4, math.radians(1.5)))) == 0.0  # IK's tolerance
    assert rising_lean(TcpPose(np.zeros(3), top_down_rotation(0.4))) == 0.0


@pytest.mark.parametrize("seed", range(3))
def test_for_a_top_down_hand_the_leaned_check_answers_as_first_hit(seed: int) -> None:
    """Sampling each box's whole volume finds a contact exactly when its bottom face does, for a
    hand pointing straight down: random clutter, random poses, both hands."""
    rng = np.random.default_rng(seed)
    clutter = np.concatenate([block(*sorted(rng.uniform(0.2, 0.6, 2)), *sorted(rng.uniform(-0.2, 0.2, 2)),
                                    float(rng.uniform(0.02, 0.30))) for _ in range(4)])
    hm = HeightMap(clutter, CFG.cell, 0.0)
    parts = [("Link3", 30), ("Link4", 12)]
    seen: set[bool] = set()
    for boxes in (PANDA.clearance_boxes, hand_spec("robotiq_2f85").clearance_boxes):
        for _ in range(25):
            tcp = np.array([[rng.uniform(0.2, 0.6), rng.uniform(-0.2, 0.2), rng.uniform(0.03, 0.4)]])
            yaw = float(rng.uniform(-math.pi, math.pi))
            arm = tcp[:, None, :] + rng.uniform(-0.15, 0.15, (1, 42, 3)) + np.array([0.0, 0.0, 0.2])
            top_down = first_hit(tcp, [yaw], arm, parts, boxes, hm, CFG)
            leaned = leaned_first_hit(tcp, np.array([tool_rotation(yaw)]), arm, parts, boxes, hm, CFG)
            assert (top_down is None) == (leaned is None), (top_down, leaned)
            seen.add(top_down is None)
    assert seen == {True, False}


def test_leaning_away_clears_a_wall_the_top_down_hand_touches_and_leaning_into_it_does_not() -> None:
    """The hand closes along x 2 cm above the table; a wall stands 3 cm to its +y side, inside
    the 3.6 cm half-width of the Franka hand's body."""
    tcp = np.array([[0.0, 0.0, 0.02]])
    no_arm = np.zeros((1, 0, 3))
    for top in (0.06, 0.5):
        hm = HeightMap(block(-0.05, 0.05, 0.03, 0.10, top), CFG.cell, 0.0)
        assert first_hit(tcp, [0.0], no_arm, [], PANDA.clearance_boxes, hm, CFG) is not None
        assert leaned_first_hit(tcp, np.array([tool_rotation(0.0, LEAN)]), no_arm, [], PANDA.clearance_boxes,
                                hm, CFG) is None
        into = leaned_first_hit(tcp, np.array([tool_rotation(0.0, -LEAN)]), no_arm, [], PANDA.clearance_boxes,
                                hm, CFG)
        assert into is not None and into.startswith("the hand (leaned)")


KNIFE_TOP = 0.015
KNIFE = block(-0.008, 0.008, -0.10, 0.10, KNIFE_TOP)


def test_a_lean_is_tried_last_first_on_the_grasp_itself_and_the_detail_says_so() -> None:
    """Only a hand leaned the negative way has a clear approach here: every top-down spot is
    tried before any lean, then the grasp itself leaned +20° and -20°, which is taken."""
    asked: list[tuple[float, float]] = []

    def problems(g: TopDownGrasp, _: HeightMap) -> tuple[str | None, str | None]:
        asked.append((float(g.position[1]), g.lean))
        return None, None if g.lean < 0 else "approach blocked: the arm (Link3) would touch a surface 20.7 cm high"

    grasp = TopDownGrasp(np.array([0.0, 0.0, KNIFE_TOP]), 0.0, 0.03)
    heights = HeightMap(np.zeros((0, 3)), CFG.cell, 0.0)
    result = relocate_if_blocked(grasp, [], KNIFE, heights, problems, lambda g: KNIFE_TOP - 0.012,
                                 FingerGeometry(), RelocateConfig())
    assert result.moved and result.pose.lean == pytest.approx(-LEAN)
    np.testing.assert_array_equal(result.pose.position, grasp.position)
    assert result.detail.endswith("the grasp moved 0.0 cm on the object and turned +0°, the hand leaned -20°, "
                                  "a clear approach")
    leaned_from = next(i for i, (_, lean) in enumerate(asked) if lean != 0.0)
    assert all(lean == 0.0 for _, lean in asked[:leaned_from])  # every top-down spot came first
    assert asked[leaned_from:] == [(0.0, pytest.approx(LEAN)), (0.0, pytest.approx(-LEAN))]
    kept = relocate_if_blocked(grasp, [], KNIFE, heights, problems, lambda g: KNIFE_TOP - 0.012,
                               FingerGeometry(), RelocateConfig(leans_deg=()))
    assert not kept.moved and kept.detail.endswith("kept")


@pytest.mark.parametrize("leans", [(0.0,), (45.0,), (-20.0,)])
def test_config_rejects_leans_outside_zero_to_45_degrees(leans: tuple[float, ...]) -> None:
    with pytest.raises(ValueError, match="leans"):
        RelocateConfig(leans_deg=leans)


def test_beside_the_tall_block_the_knife_is_picked_with_the_hand_leaned() -> None:
    """sim-dev's ``cut/knife/1``: every top-down spot of the knife puts the wrist links on the
    21 cm wood block (``docs/results/sim_execution.md``). Relocation now leans the hand, and
    physics picks the knife (before: kept and missed)."""
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

    spec = next(s for s in make_episode_specs(load_sim_labels(SIM_DEV_LABELS), layouts=2) if s.id == "cut/knife/1")
    config = PipelineConfig()
    with SimEnv() as env:
        env.reset(spec.scene)
        env.robot.reset_home()
        obs = env.capture()
        encoder = default_encoder(1)
        eager = perceive(env, encoder, config, obs)
        knife = eager.target_roi
        assert knife is not None and eager.rois[knife].usable
        chosen = eager.rois[knife].usable[0]
        moved, why = relocated_grasp(env, obs, eager.rois[knife], chosen, config)
        assert why.startswith("approach blocked: the arm (Link3)") and "leaned" in why, why
        assert moved.pose is not None and moved.pose.lean != 0.0
        # the robot's lazy path leans the same grasp the same way
        lazy = perceive_for_pick(env, encoder, config, obs)[knife]
        lazy_moved, lazy_why = relocate_choice(env, config, obs, lazy, lazy.as_roi("knife").grasps[0])
        assert lazy_why == why and lazy_moved.pose is not None
        assert lazy_moved.pose.lean == moved.pose.lean
        np.testing.assert_allclose(lazy_moved.pose.position, moved.pose.position, atol=1e-6)
        env.robot.reset_home()
        picked = execute_pick(env, moved.pose, env.scene.target.body_id, config.pick)
        assert picked.outcome is Outcome.SUCCESS, picked.detail
