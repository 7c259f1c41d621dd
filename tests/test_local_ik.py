"""Newton IK for seeded waypoints (``sim.local_ik``) replaces pybullet's solver where it applies.

Why these tests: the pick's plan decides which grasps are reachable and the joints the arm follows.
The Newton solver is only a faster way to the same answers, so it must (1) use the same kinematic
model as the checks, (2) land on the posture pybullet's solver lands on from the same seed, not on
another branch, (3) refuse what it cannot do (far seeds, flipped orientations), leaving those to
pybullet, and (4) give the same reachability answers on whole plans.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest

from craft_e.runtime.sim.gripper import GripperConfig
from craft_e.runtime.sim.kinematics import axis_angle_matrix, load_chain
from craft_e.runtime.sim.local_ik import ChainIK
from craft_e.runtime.sim.robot import HOME_Q, CR3Robot, top_down_rotation
from craft_e.runtime.sim.robot_urdf import TCP_LINK, robot_urdf_path


@pytest.mark.parametrize("hand", ["panda", "robotiq_2f85"])
def test_pose_matches_the_chain_model(hand: str) -> None:
    chain = load_chain(robot_urdf_path(hand), TCP_LINK)
    ik = ChainIK(chain)
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.uniform(-math.pi, math.pi, size=6)
        rotation, position = ik.pose(q)
        reference = chain.forward(q)
        assert np.allclose(rotation, reference[:3, :3], atol=1e-12)
        assert np.allclose(position, reference[:3, 3], atol=1e-12)


def _pybullet_only(robot: CR3Robot) -> CR3Robot:
    robot.config = dataclasses.replace(robot.config, ik_local=False)
    return robot


def test_newton_reaches_the_pose_pybullet_reaches_from_the_same_seed(
    bare_robot: Callable[..., CR3Robot],
) -> None:
    local, reference = bare_robot(), _pybullet_only(bare_robot())
    rng = np.random.default_rng(1)
    newton_answers = 0
    for _ in range(40):
        seed_position = np.array([rng.uniform(0.25, 0.5), rng.uniform(-0.3, 0.3), rng.uniform(0.05, 0.3)])
        yaw = float(rng.uniform(-math.pi / 2, math.pi / 2))
        seed = reference.solve_ik(seed_position, yaw)
        if not seed.ok(reference.config):
            continue
        target = seed_position + rng.normal(scale=0.01, size=3)
        turned = yaw + float(rng.normal(scale=0.2))
        assert local._solve_local(target, top_down_rotation(turned), seed.q) is not None
        newton_answers += 1
        ours, theirs = local.solve_ik(target, turned, seed=seed.q), reference.solve_ik(target, turned, seed=seed.q)
        assert ours.ok(local.config) and theirs.ok(reference.config)
        assert ours.position_error < 1e-6 and ours.angle_error < 1e-5
        assert ours.position_error <= theirs.position_error + 1e-9
        # The same posture, not another branch (elbow or wrist flipped: ~1 rad or more). pybullet
        # accepts answers up to its tolerances (mm), where the elbow joints may be off by 0.06.
        assert float(np.abs(ours.q - theirs.q).max()) < 0.1
    assert newton_answers >= 30


def test_newton_declines_far_seeds_and_flipped_orientations() -> None:
    ik = ChainIK(load_chain(robot_urdf_path(GripperConfig().hand), TCP_LINK))
    rotation, position = ik.pose(HOME_Q)
    assert ik.solve(rotation, position + np.array([0.2, 0.0, 0.0]), HOME_Q) is None  # 20 cm away
    flipped = rotation @ np.diag([-1.0, 1.0, -1.0])  # a half turn: sin(angle) is 0 there too
    assert ik.solve(flipped, position, HOME_Q) is None
    found = ik.solve(rotation, position + np.array([0.01, -0.01, 0.005]), HOME_Q)
    assert found is not None
    q, reached_rotation, reached = found
    assert np.allclose(reached, position + np.array([0.01, -0.01, 0.005]), atol=1e-6)
    assert np.allclose(ik.pose(q)[1], reached, atol=1e-12)
    assert np.allclose(reached_rotation, rotation, atol=1e-6)


def test_straight_line_plans_agree_with_pybullet(bare_robot: Callable[..., CR3Robot]) -> None:
    """Every waypoint of lines across the workspace (the moves of a pick: descents, lifts, a
    transport to the drop zone with a quarter turn of the wrist) is reachable with Newton exactly
    when it is with pybullet, in the same posture."""
    local, reference = bare_robot(), _pybullet_only(bare_robot())
    start = reference.solve_ik((0.4, 0.0, 0.2), 0.0)
    assert start.ok(reference.config)
    lines = [((0.4, 0.0, 0.05), 0.0), ((0.3, 0.25, 0.2), 0.3), ((0.02, -0.4, 0.17), math.pi / 2),
             ((0.55, 0.2, 0.1), -0.8)]
    for goal, yaw in lines:
        ours, theirs = local.plan_linear(start.q, goal, yaw), reference.plan_linear(start.q, goal, yaw)
        assert len(ours) == len(theirs)
        assert [s.ok(local.config) for s in ours] == [s.ok(reference.config) for s in theirs]
        assert float(np.abs(ours[-1].q - theirs[-1].q).max()) < 0.1
        assert max(s.position_error for s in ours) < 1e-6


def _numpy_reference_solve(
    ik: ChainIK, rotation: np.ndarray, position: np.ndarray, seed: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``ChainIK.solve`` as it was written before its elementwise parts moved to Python floats:
    every step on numpy arrays (the oracle that the faster form must equal bit for bit)."""
    cfg = ik.config
    target = np.asarray(position, dtype=np.float64)
    q = np.array(seed, dtype=np.float64)
    for step in range(cfg.max_steps + 1):
        end, frames = ik._walk(q)
        turn = rotation @ end[:3, :3].T
        r = turn.tolist()
        skew = np.array([r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]]) * 0.5
        cosine = 0.5 * (r[0][0] + r[1][1] + r[2][2] - 1.0)
        if cosine <= 0.999:
            sine = float(np.linalg.norm(skew))
            skew = skew * (math.atan2(sine, cosine) / sine) if sine > 1e-12 else skew
        residual = np.concatenate([target - end[:3, 3], skew])
        cos_angle = 0.5 * (float(np.trace(turn)) - 1.0)
        if step == 0 and (float(np.linalg.norm(residual[:3])) > cfg.max_seed_distance
                          or cos_angle < math.cos(cfg.max_seed_angle)):
            return None
        if float(np.abs(residual).max()) <= cfg.tolerance:
            return (q, end[:3, :3], end[:3, 3]) if cos_angle > 0.0 else None
        if step == cfg.max_steps:
            return None
        axes = frames[:, :3, :3] @ ik._axes[:, :, None]
        lever = end[:3, 3, None] - frames[:, :3, 3, None]
        jacobian = np.empty((6, len(axes)))
        jacobian[0] = axes[:, 1, 0] * lever[:, 2, 0] - axes[:, 2, 0] * lever[:, 1, 0]
        jacobian[1] = axes[:, 2, 0] * lever[:, 0, 0] - axes[:, 0, 0] * lever[:, 2, 0]
        jacobian[2] = axes[:, 0, 0] * lever[:, 1, 0] - axes[:, 1, 0] * lever[:, 0, 0]
        jacobian[3:] = axes[:, :, 0].T
        try:
            delta = np.linalg.solve(jacobian, residual)
        except np.linalg.LinAlgError:
            return None
        if float(np.abs(delta).max()) > cfg.max_joint_step:
            return None
        q = q + delta
    return None


def test_newton_equals_its_all_numpy_form_bit_for_bit() -> None:
    """The solver's residual, Jacobian and checks run on Python floats for speed; IK answers
    decide reachability and the joints the arm follows, so they must not move by a single bit
    (else every sim table would change): compared with the all-numpy form on seeded near and
    far, reachable and unreachable waypoints, including a singular pose (the arm stretched)."""
    ik = ChainIK(load_chain(robot_urdf_path(GripperConfig().hand), TCP_LINK))
    rng = np.random.default_rng(7)
    solved = declined = 0
    for i in range(400):
        q = np.asarray(HOME_Q) + rng.normal(scale=0.6, size=6)
        rotation, position = ik.pose(q)
        turn = rng.normal(scale=0.05 if i % 4 else 0.8, size=3)
        angle = float(np.linalg.norm(turn))
        target_rotation = axis_angle_matrix(turn / angle, angle) @ rotation
        target = position + rng.normal(scale=0.012 if i % 5 else 0.04, size=3)
        seed = q + rng.normal(scale=0.01, size=6)
        ours, reference = ik.solve(target_rotation, target, seed), _numpy_reference_solve(ik, target_rotation, target, seed)
        assert (ours is None) == (reference is None)
        if ours is not None and reference is not None:
            solved += 1
            for a, b in zip(ours, reference, strict=True):
                assert np.array_equal(a, b)
        else:
            declined += 1
    stretched = np.zeros(6)  # every joint at zero: the arm straight up, its Jacobian singular
    rotation, position = ik.pose(stretched)
    assert (ik.solve(rotation, position + 0.001, stretched) is None) == (
        _numpy_reference_solve(ik, rotation, position + 0.001, stretched) is None)
    assert solved > 200 and declined > 20


def test_the_public_solve_is_the_fallback_with_the_same_answers(monkeypatch: pytest.MonkeyPatch) -> None:
    """The fast path calls numpy's private solve kernel; a numpy without it must still work and
    give the same joints (the public ``numpy.linalg.solve`` wraps the same kernel)."""
    import craft_e.runtime.sim.local_ik as local_ik

    ik = ChainIK(load_chain(robot_urdf_path(GripperConfig().hand), TCP_LINK))
    rotation, position = ik.pose(HOME_Q)
    target = position + np.array([0.012, -0.008, 0.004])
    fast = ik.solve(rotation, target, HOME_Q)
    monkeypatch.setattr(local_ik, "_SOLVE1", None)
    public = ik.solve(rotation, target, HOME_Q)
    assert fast is not None and public is not None
    assert all(np.array_equal(a, b) for a, b in zip(fast, public, strict=True))
    singular = np.zeros((6, 6))
    assert np.isnan(local_ik._solve_linear(singular, np.ones(6))).all()
