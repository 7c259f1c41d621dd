"""The CR3 loads with the documented URDF fixes, its FK model agrees with pybullet, IK reaches."""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pybullet as p
import pytest

from craft_e.runtime.sim.assets import shared_path
from craft_e.runtime.sim.robot import CR3Robot, joint_targets, top_down_rotation
from craft_e.runtime.sim.robot_urdf import (
    CR3_URDF,
    FINGERTIP_BELOW_TCP,
    robot_urdf_path,
)


@pytest.fixture(scope="module")
def robot(bare_robot: Callable[..., CR3Robot]) -> CR3Robot:
    return bare_robot()


def test_composed_urdf_applies_the_fixes_and_leaves_shared_untouched() -> None:
    upstream = shared_path(CR3_URDF).read_text(encoding="utf-8")
    assert "package://dobot_rviz" in upstream, "shared CR3 URDF was modified"
    root = ET.parse(robot_urdf_path()).getroot()
    meshes = [m.attrib["filename"] for m in root.iter("mesh")]
    assert meshes and all(not f.startswith("package://") for f in meshes)
    assert all(f.startswith("/") for f in meshes)
    arm_limits = [j.find("limit") for j in root.findall("joint") if j.attrib["name"][:5] == "joint"]
    assert len(arm_limits) == 6
    assert all(float(lim.attrib["effort"]) > 0 for lim in arm_limits if lim is not None)
    assert all(float(lim.attrib["velocity"]) > 0 for lim in arm_limits if lim is not None)
    names = [m.attrib["name"] for link in root.iter("link") for m in link.iter("material")]
    cr3_names = [n for n in names if n.startswith("cr3_")]
    assert len(cr3_names) == 7 and len(set(cr3_names)) == 7 and "" not in names


def test_fk_model_matches_pybullet(robot: CR3Robot) -> None:
    rng = np.random.default_rng(0)
    client = robot.client
    saved = robot.joint_positions()
    for _ in range(5):
        q = rng.uniform(-2.0, 2.0, 6)
        for joint, value in zip(robot.arm_joints, q, strict=True):
            p.resetJointState(robot.body_id, joint, float(value), physicsClientId=client)
        measured = robot.tcp_pose()
        model = robot.forward(q)
        assert np.allclose(measured.position, model.position, atol=1e-6)
        assert np.allclose(measured.rotation, model.rotation, atol=1e-6)
    for joint, value in zip(robot.arm_joints, saved, strict=True):
        p.resetJointState(robot.body_id, joint, float(value), physicsClientId=client)


def test_tcp_sits_between_the_finger_tips(robot: CR3Robot) -> None:
    hand_state = p.getLinkState(robot.body_id, robot.hand_link, physicsClientId=robot.client)
    tcp = robot.tcp_pose()
    offset = robot.gripper.hand.tcp_offset
    assert np.linalg.norm(tcp.position - np.array(hand_state[4])) == pytest.approx(offset)
    robot.gripper.close()  # the Robotiq's tips reach furthest when closed
    tips = [
        p.getAABB(robot.body_id, link, physicsClientId=robot.client)[0][2]
        for link in robot.gripper.pads
    ]  # gripper points down at home: the lowest AABB point is the tip
    robot.gripper.open()
    for tip in tips:
        assert tcp.position[2] - tip == pytest.approx(FINGERTIP_BELOW_TCP, abs=0.003)


@pytest.mark.parametrize(
    ("position", "yaw"),
    [
        ((0.30, 0.00, 0.10), 0.0),
        ((0.45, 0.15, 0.05), 0.8),
        ((0.35, -0.18, 0.20), -1.2),
        ((0.25, 0.10, 0.03), 1.5),
    ],
)
def test_ik_motion_reaches_top_down_pose_within_5mm(
    robot: CR3Robot, position: tuple[float, float, float], yaw: float
) -> None:
    solution = robot.move_to(position, robot.nearest_yaw(yaw, robot.tcp_pose().yaw))
    assert solution.ok(robot.config), solution
    reached = robot.tcp_pose()  # after executing the motion in physics, not the model
    assert np.linalg.norm(reached.position - np.array(position)) < 0.005
    down = top_down_rotation(yaw)[:, 2]
    assert math.degrees(math.acos(float(reached.rotation[:, 2] @ down))) < 2.0
    axis_error = abs(math.sin(reached.yaw - yaw))  # parallel grasp: yaw and yaw + pi agree
    assert axis_error < math.sin(math.radians(2.0))


def test_unreachable_pose_is_reported_not_executed(robot: CR3Robot) -> None:
    before = robot.joint_positions()
    solution = robot.move_to((1.2, 0.0, 0.1), 0.0)
    assert not solution.ok(robot.config)
    assert solution.position_error > 0.1
    assert np.allclose(robot.joint_positions(), before, atol=1e-3)


def test_gripper_opens_and_closes_on_nothing(robot: CR3Robot) -> None:
    robot.gripper.open()
    assert robot.gripper.width() == pytest.approx(robot.gripper.hand.stroke, abs=0.002)
    robot.gripper.close()
    assert robot.gripper.width() < robot.gripper.config.min_held_width
    assert robot.gripper.check_grasp() is None
    robot.gripper.open()


#: The arm at the end of a lift in sim-val's carry/mug/0 (the mug's fitting grasp at x = 0.53 m):
#: reached out with the elbow nearly straight (joint3 = -0.039), where the Jacobian is singular.
STRETCHED_Q = np.array([-0.060, -0.973, -0.039, -0.559, 1.571, 0.225])
DROP_ZONE_AT_LIFT_HEIGHT = (0.02, -0.40, 0.203)


def test_a_missed_waypoint_from_a_stretched_arm_is_reached_in_half_steps(
    bare_robot: Callable[..., CR3Robot],
) -> None:
    """Why: this carry was reported "drop zone unreachable" and a fitting grasp was rejected,
    because the first 2 cm back towards the base from a straight elbow needs ~0.4 rad of elbow
    at once. Without the split the first waypoint is missed (by ~1 cm); with it, every waypoint
    of the line is reached, in the same elbow branch as the arm's home posture (joint3 < 0),
    and the extra waypoints lie on the same straight line."""
    split, single = bare_robot(), bare_robot()
    single.config = dataclasses.replace(single.config, ik_split_failed=0)
    yaw = -math.pi
    missed = single.plan_linear(STRETCHED_Q, DROP_ZONE_AT_LIFT_HEIGHT, yaw)
    assert not missed[0].ok(single.config) and missed[0].position_error > 0.005
    line = split.plan_linear(STRETCHED_Q, DROP_ZONE_AT_LIFT_HEIGHT, yaw)
    assert all(s.ok(split.config) for s in line)
    assert len(line) == len(missed) + 1  # one waypoint split in two
    assert line[1].q[2] < -0.2  # the elbow bent, on home's side
    start = split.forward(STRETCHED_Q).position
    goal = np.array(DROP_ZONE_AT_LIFT_HEIGHT)
    for s in line:
        tcp = split.forward(s.q).position
        off_line = np.linalg.norm(np.cross(tcp - start, goal - start)) / np.linalg.norm(goal - start)
        assert off_line < 0.005
    assert np.linalg.norm(split.forward(line[-1].q).position - goal) < 0.005


def test_a_line_that_never_misses_is_planned_as_before(bare_robot: Callable[..., CR3Robot]) -> None:
    """The split only runs on a miss: a reachable line gets the same waypoints, bit for bit."""
    split, single = bare_robot(), bare_robot()
    single.config = dataclasses.replace(single.config, ik_split_failed=0)
    start_q = split.solve_ik((0.35, 0.05, 0.20), 0.3).q
    a = split.plan_linear(start_q, (0.30, -0.20, 0.15), 0.3)
    b = single.plan_linear(start_q, (0.30, -0.20, 0.15), 0.3)
    assert all(s.ok(split.config) for s in a) and len(a) == len(b) > 5
    assert all(np.array_equal(x.q, y.q) for x, y in zip(a, b, strict=True))



def test_waypoints_that_differ_in_their_last_bits_move_the_arm_identically(
    bare_robot: Callable[..., CR3Robot], monkeypatch: pytest.MonkeyPatch,
) -> None:
    """IK's answers depend on the host's numpy kernels by up to ~1e-10 rad
    (``JOINT_TARGET_DECIMALS``); the arm is sent the same targets whatever those digits are, so
    the physics ends bit for bit where it would on another host. Sent unrounded, the same two
    paths end apart."""
    planner = bare_robot()
    line = planner.plan_linear(planner.joint_positions(), (0.30, -0.20, 0.15), 0.3)
    assert len(line) > 5 and all(s.ok(planner.config) for s in line)
    waypoints = [s.q for s in line]
    nudged = [q + 3e-11 for q in waypoints]  # as much as other CPU kernels move IK's answers
    assert not any(np.array_equal(a, b) for a, b in zip(waypoints, nudged, strict=True))

    def played(path: list[npt.NDArray[np.float64]]) -> npt.NDArray[np.float64]:
        robot = bare_robot()
        robot.follow(path, steps=80)
        return robot.joint_positions()

    assert np.array_equal(played(waypoints), played(nudged))
    assert np.array_equal(joint_targets(waypoints[0]), joint_targets(nudged[0]))
    monkeypatch.setattr("craft_e.runtime.sim.robot.joint_targets", lambda q: q)
    assert not np.array_equal(played(waypoints), played(nudged))
