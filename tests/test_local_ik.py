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

from craft_e.runtime.sim import local_ik
from craft_e.runtime.sim.gripper import GripperConfig
from craft_e.runtime.sim.kinematics import axis_angle_matrix, load_chain
from craft_e.runtime.sim.local_ik import ChainIK
from craft_e.runtime.sim.robot import (
    HOME_Q,
    CR3Robot,
    joint_targets,
    rotation_angle,
    top_down_rotation,
)
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


@pytest.mark.parametrize("hand", ["panda", "robotiq_2f85"])
def test_joint_frames_match_the_chain_model(hand: str) -> None:
    """The clearance check reads the arm's joint frames from the compiled walk (fixed joints
    included): the frames ``SerialChain.frames`` gives, by the same names, to float rounding."""
    chain = load_chain(robot_urdf_path(hand), TCP_LINK)
    ik = ChainIK(chain)
    rng = np.random.default_rng(2)
    for _ in range(50):
        q = rng.uniform(-math.pi, math.pi, size=6)
        ours, reference = ik.joint_frames(ik.walk(q)[1]), chain.frames(q)
        assert ours.keys() == reference.keys()
        for name, frame in reference.items():
            assert np.allclose(ours[name], frame, atol=1e-12), name


def test_the_compiled_check_equals_the_robots_python_check(bare_robot: Callable[..., CR3Robot]) -> None:
    """``checked_answer`` (Newton's answers) wraps joints into the limits and measures the errors
    as ``_into_limits_checked`` and ``rotation_angle`` do for pybullet's answers: the same joints
    and verdicts, errors to rounding, on joints inside, a turn outside and beyond the limits."""
    robot = bare_robot()
    rng = np.random.default_rng(5)
    for _ in range(300):
        q = rng.uniform(-9.0, 9.0, size=6)
        reached = axis_angle_matrix(rng.normal(size=3), float(rng.uniform(0, math.pi)))
        wanted = axis_angle_matrix(rng.normal(size=3), float(rng.uniform(0, math.pi)))
        at, target = rng.normal(size=3), rng.normal(size=3)
        wrapped, within, position_error, angle_error = local_ik.checked_answer(
            q, reached, at, wanted, target, robot._lower, robot._upper)
        expected, expected_within = robot._into_limits_checked(q)
        assert np.array_equal(wrapped, expected) and within == expected_within
        assert math.isclose(position_error, float(np.linalg.norm(at - target)), rel_tol=1e-12)
        assert math.isclose(angle_error, rotation_angle(reached, wanted), rel_tol=1e-9, abs_tol=1e-12)


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


def _numpy_walk(ik: ChainIK, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The chain's walk in numpy (the form the solver had before it was compiled): end pose and
    every joint's frame after its motion."""
    angles = np.asarray(q, dtype=np.float64)[:, None, None]
    motion = np.zeros_like(ik._origins)
    motion[:, 3, 3] = 1.0
    motion[:, :3, :3] = np.eye(3) + np.sin(angles) * ik._cross + (1.0 - np.cos(angles)) * ik._cross2
    local = ik._origins @ motion
    frames = np.empty_like(local)
    pose = frames[0] = local[0]
    for i in range(1, len(local)):
        pose = frames[i] = pose @ local[i]
    return pose @ ik._tail, frames


def _numpy_reference_solve(
    ik: ChainIK, rotation: np.ndarray, position: np.ndarray, seed: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``ChainIK.solve`` as an all-numpy oracle: the same Newton steps on numpy arrays, with
    LAPACK's solve."""
    cfg = ik.config
    target = np.asarray(position, dtype=np.float64)
    q = np.array(seed, dtype=np.float64)
    for step in range(cfg.max_steps + 1):
        end, frames = _numpy_walk(ik, q)
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


def test_compiled_newton_equals_its_numpy_form_to_rounding() -> None:
    """The solver is compiled (plain loops, its own 6x6 elimination); IK answers decide
    reachability and the joints the arm follows, so against the all-numpy form on seeded near
    and far, reachable and unreachable waypoints (and a singular pose, the arm stretched) it
    must accept and decline the same waypoints, reach them to ~1e-13, and give the arm the same
    targets after their rounding to 1e-5 rad (``robot.joint_targets``), so no sim table moves."""
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
                assert float(np.abs(a - b).max()) < 1e-11
            assert np.array_equal(joint_targets(ours[0]), joint_targets(reference[0]))
        else:
            declined += 1
    stretched = np.zeros(6)  # every joint at zero: the arm straight up, its Jacobian singular
    rotation, position = ik.pose(stretched)
    assert (ik.solve(rotation, position + 0.001, stretched) is None) == (
        _numpy_reference_solve(ik, rotation, position + 0.001, stretched) is None)
    assert solved > 200 and declined > 20


def test_the_elimination_solves_as_lapack_and_gives_nan_when_singular() -> None:
    """``_solve6`` stands in for ``numpy.linalg.solve`` (LAPACK) inside the compiled solver: the
    same solutions to rounding on random and badly scaled systems, NaN (Newton declines) when
    the matrix is singular."""
    rng = np.random.default_rng(3)
    for scale in (1.0, 1e-3, 1e3):
        for _ in range(100):
            a = rng.normal(size=(6, 6)) * scale
            b = rng.normal(size=6)
            expected = np.linalg.solve(a, b)
            got = local_ik._solve6(a.copy(), b.copy())
            assert np.allclose(got, expected, rtol=1e-9, atol=1e-12 / scale)
    assert np.isnan(local_ik._solve6(np.zeros((6, 6)), np.ones(6))).all()
