"""Forward kinematics and IK bookkeeping were sped up; their numbers must not move by one bit.

Why: the robot's one IK plan per scene (``plan_pick``, ~100 solver rounds) checks every solver
answer with forward kinematics and wraps joints into their limits. Those numbers decide which
waypoints are accepted (tolerances of 5 mm / 2 degrees), so any change of rounding could flip a
borderline pick. The references below are the replaced implementations: numpy temporaries,
``np.eye`` and per-element numpy scalars.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from craft_e.runtime.sim.gripper import GripperConfig
from craft_e.runtime.sim.kinematics import SerialChain, _rodrigues, load_chain
from craft_e.runtime.sim.robot import CR3Robot
from craft_e.runtime.sim.robot_urdf import TCP_LINK, robot_urdf_path


def _reference_forward(chain: SerialChain, q: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    values = iter(np.asarray(q, dtype=np.float64))
    for joint in chain.joints:
        pose = pose @ joint.origin
        if not joint.movable:
            continue
        motion = np.eye(4)
        value = float(next(values))
        if joint.kind == "prismatic":
            motion[:3, 3] = joint.axis * value
        else:
            k = joint.axis / np.linalg.norm(joint.axis)
            kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
            motion[:3, :3] = _rodrigues(kx, kx @ kx, value)
        pose = pose @ motion
    return pose


def _reference_into_limits(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    wrapped = q.copy()
    for i in range(len(wrapped)):
        for shift in (2 * math.pi, -2 * math.pi):
            if not lower[i] <= wrapped[i] <= upper[i]:
                candidate = wrapped[i] + shift
                if lower[i] <= candidate <= upper[i]:
                    wrapped[i] = candidate
    return wrapped


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


@pytest.fixture(scope="module")
def chain() -> SerialChain:
    return load_chain(robot_urdf_path(GripperConfig().hand), TCP_LINK)


def test_forward_kinematics_bit_for_bit(chain: SerialChain) -> None:
    rng = np.random.default_rng(0)
    for scale in (1e-7, 1.0, 3.0):
        for _ in range(500):
            q = rng.uniform(-math.pi, math.pi, 6) * scale
            assert _same_bits(chain.forward(q), _reference_forward(chain, q))
    q = np.array([0.0, -0.0, math.pi, -math.pi, 2 * math.pi, 1e-300])
    assert _same_bits(chain.forward(q), _reference_forward(chain, q))


def _limits_only_robot() -> tuple[CR3Robot, np.ndarray, np.ndarray]:
    """A CR3Robot with only its joint limits set (no physics client): what the limit checks read."""
    robot = CR3Robot.__new__(CR3Robot)
    lower = np.array([-6.2, -3.1, -2.7, -6.2, -6.2, -6.2])
    upper = np.array([6.2, 3.1, 2.7, 6.2, 6.2, 6.2])
    robot._lower, robot._upper = lower, upper
    robot._limit_pairs = list(zip(lower.tolist(), upper.tolist(), strict=True))
    return robot, lower, upper


def test_into_limits_bit_for_bit() -> None:
    robot, lower, upper = _limits_only_robot()
    rng = np.random.default_rng(1)
    for _ in range(2000):
        q = rng.uniform(-12, 12, 6)
        assert _same_bits(robot._into_limits(q), _reference_into_limits(q, lower, upper))


def test_forward_and_frames_is_one_walk_of_forward_and_frames(chain: SerialChain) -> None:
    """The clearance check walks the chain once per pose for the TCP and the joint frames
    (``CR3Robot.forward_and_frames``): the same matrices as ``forward`` and ``frames`` apart."""
    rng = np.random.default_rng(2)
    for _ in range(200):
        q = rng.uniform(-math.pi, math.pi, 6)
        end, frames = chain.forward_and_frames(q)
        assert _same_bits(end, chain.forward(q))
        separate = chain.frames(q)
        assert list(frames) == list(separate)
        assert all(_same_bits(frames[name], separate[name]) for name in separate)


def test_limit_check_and_rotation_angle_equal_their_numpy_forms() -> None:
    """``_into_limits_checked``'s flag is ``np.all(q >= lower) and np.all(q <= upper)`` (NaN:
    outside) and ``rotation_angle`` sums the trace as ``np.trace`` does: the same answers, bit for
    bit, on the IK path that checks both at every waypoint."""
    from craft_e.runtime.sim.robot import rotation_angle
    from craft_e.runtime.sim.transforms import quat_to_matrix, rpy_to_quat

    robot, lower, upper = _limits_only_robot()
    rng = np.random.default_rng(3)
    for k in range(2000):
        q = rng.uniform(-12, 12, 6)
        if k % 50 == 0:
            q[k % 6] = np.nan
        wrapped, within = robot._into_limits_checked(q)
        assert _same_bits(wrapped, robot._into_limits(q))
        assert within == bool(np.all(wrapped >= lower) and np.all(wrapped <= upper))
    for _ in range(500):
        a = quat_to_matrix(rpy_to_quat(*rng.uniform(-math.pi, math.pi, 3)))
        b = quat_to_matrix(rpy_to_quat(*rng.uniform(-math.pi, math.pi, 3)))
        cos = (np.trace(a.T @ b) - 1.0) / 2.0
        assert rotation_angle(a, b) == float(math.acos(max(-1.0, min(1.0, cos))))
