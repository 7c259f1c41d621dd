"""The grippers of the simulated CR3: the Robotiq 2F-85 model, its grip, and a pick of a cube.

The Robotiq's linkage only works in pybullet through gear constraints plus a position servo of
its followers (the URDF's mimic tags are ignored), so these tests check what would break first:
the joint limits, the opening measured between the pads, a firm symmetric grip on a box of known
width, a whole pick of a free cube, and a long bar carried off-centre. The Franka hand picks the
same cube.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pybullet as p
import pytest

from craft_e.runtime.grasp.geometry import TopDownGrasp
from craft_e.runtime.sim.env import EnvConfig, SimEnv
from craft_e.runtime.sim.episode import Outcome, execute_pick
from craft_e.runtime.sim.gripper import GripperConfig
from craft_e.runtime.sim.hands import DEFAULT_HAND, FINGERTIP_BELOW_TCP, ROBOTIQ_2F85, hand_spec
from craft_e.runtime.sim.robot import CR3Robot
from craft_e.runtime.sim.scene import Scene, SceneSpec

EASY = SceneSpec("pour", "mustard_bottle", ("foam_brick", "knife", "apple", "stapler_2"), seed=2)


@pytest.fixture(scope="module")
def robot(bare_robot: Callable[..., CR3Robot]) -> CR3Robot:
    return bare_robot(GripperConfig(hand="robotiq_2f85"))


def _joint(robot: CR3Robot, name: str) -> tuple[float, float]:
    for j in range(p.getNumJoints(robot.body_id, physicsClientId=robot.client)):
        info = p.getJointInfo(robot.body_id, j, physicsClientId=robot.client)
        if info[1].decode() == name:
            return float(info[8]), float(info[9])
    raise AssertionError(f"joint {name} missing")


def test_robotiq_loads_with_its_limits_and_masses(robot: CR3Robot) -> None:
    assert DEFAULT_HAND == "panda" and robot.gripper.hand is ROBOTIQ_2F85
    assert _joint(robot, "finger_joint") == pytest.approx((0.0, 0.8))
    assert _joint(robot, "left_inner_finger_joint") == pytest.approx((-0.8757, 0.0))
    masses = [p.getDynamicsInfo(robot.body_id, link, physicsClientId=robot.client)[0]
              for link in (*robot.gripper.left_links, *robot.gripper.right_links)]
    assert max(masses) < 0.1  # upstream has no inertials: pybullet would make each 1 kg
    with pytest.raises(ValueError, match="robotiq_2f85"):
        hand_spec("gripper3000")


def test_robotiq_opens_to_85mm_and_closes_with_the_tips_below_the_tcp(robot: CR3Robot) -> None:
    robot.gripper.open()
    assert robot.gripper.width() == pytest.approx(0.086, abs=0.002)
    robot.gripper.close()
    assert robot.gripper.width() < 0.004  # the pads' tips meet first: 3.4 mm between the origins
    assert robot.gripper.check_grasp() is None
    tips = min(p.getAABB(robot.body_id, link, physicsClientId=robot.client)[0][2]
               for link in robot.gripper.pads)  # pointing down: the lowest point is the tip
    assert robot.tcp_pose().position[2] - tips == pytest.approx(FINGERTIP_BELOW_TCP, abs=0.002)
    robot.gripper.open()


@pytest.mark.parametrize("width", [0.02, 0.05])
def test_robotiq_closes_firmly_and_symmetrically_on_a_fixed_box(
    robot: CR3Robot, width: float
) -> None:
    client = robot.client
    tcp = robot.tcp_pose()
    shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.01, width / 2, 0.02],
                                   physicsClientId=client)
    yaw = tcp.yaw - math.pi / 2  # the box's y (its width) along the closing axis
    box = p.createMultiBody(0, shape, basePosition=list(tcp.position - 0.005 * tcp.rotation[:, 2]),
                            baseOrientation=p.getQuaternionFromEuler([0, 0, yaw]),
                            physicsClientId=client)
    try:
        robot.gripper.close()
        assert robot.gripper.check_grasp() == box
        assert robot.gripper.width() == pytest.approx(width, abs=0.004)
        left, right = robot.gripper.pad_forces(box)
        # measured 15-27 N (GripperConfig); the real 2F-85 squeezes with 20-235 N
        assert left > 12.0 and right > 12.0, (left, right)
        assert max(left, right) / min(left, right) < 2.0
    finally:
        robot.gripper.open()
        p.removeBody(box, physicsClientId=client)


def _free_spot(scene: Scene, min_gap: float) -> tuple[float, float]:
    """The reachable table point farthest from every object (at least ``min_gap`` away)."""
    positions = np.array([scene.pose(o.body_id)[0][:2] for o in scene.objects])
    grid = np.array([(x, y) for x in np.linspace(0.25, 0.45, 9) for y in np.linspace(-0.2, 0.2, 17)])
    gaps = np.min(np.linalg.norm(grid[:, None, :] - positions[None], axis=2), axis=1)
    assert gaps.max() > min_gap
    x, y = grid[int(np.argmax(gaps))]
    return float(x), float(y)


def _cube_pick(hand: str) -> Outcome:
    with SimEnv(EnvConfig(gripper=GripperConfig(hand=hand))) as env:  # type: ignore[arg-type]
        x, y = _free_spot(env.reset(EASY), 0.1)
        half = 0.02
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[half] * 3, physicsClientId=env.client)
        cube = p.createMultiBody(0.1, shape, basePosition=[x, y, half + 0.001],
                                 baseOrientation=p.getQuaternionFromEuler([0, 0, 0.3]),
                                 physicsClientId=env.client)
        p.changeDynamics(cube, -1, lateralFriction=0.8, spinningFriction=0.002,
                         physicsClientId=env.client)
        env.step(60)
        grasp = TopDownGrasp(position=np.array([x + 0.006, y, 2 * half]), yaw=0.3, width_m=0.04)
        result = execute_pick(env, grasp, cube)
        assert result.wrist_frames == 1
        # nothing stands near the cube: the hand reaches its grasp and touches no other object
        assert result.descent_gap is not None and abs(result.descent_gap) < 0.01
        assert result.touching == ()
        # the grasp was 6 mm off the cube's centre along x: the wrist look moves it back along
        # the closing axis (its x component is 6 mm * cos 0.3)
        assert result.wrist_shift == pytest.approx(-0.006 * math.cos(0.3), abs=0.002)
        return result.outcome


def test_robotiq_picks_a_cube_at_a_known_pose() -> None:
    assert _cube_pick("robotiq_2f85") is Outcome.SUCCESS


def test_default_panda_hand_picks_the_cube() -> None:
    assert _cube_pick("panda") is Outcome.SUCCESS


def test_each_hand_brings_its_own_finger_geometry_to_the_grasp_checks() -> None:
    """The finger check and grasp refinement must model the hand that will close: with
    ``--gripper robotiq_2f85`` the pads open to its 85 mm stroke and are 22 mm wide (the URDF's
    pad box), not the Franka hand's 80 mm and 20 mm."""
    import xml.etree.ElementTree as ET

    from craft_e.runtime.sim.assets import shared_path
    from craft_e.runtime.sim.episode import sim_configs
    from craft_e.runtime.sim.fingers import FingerGeometry
    from craft_e.runtime.sim.hands import HANDS
    from craft_e.runtime.sim.robot_urdf import ROBOTIQ_URDF

    _, _, franka = sim_configs("panda", wrist_look=True)
    _, _, robotiq = sim_configs("robotiq_2f85", wrist_look=True)
    assert franka == FingerGeometry()
    for spec, fingers in ((HANDS["panda"], franka), (HANDS["robotiq_2f85"], robotiq)):
        assert fingers == spec.fingers
        assert abs(2 * fingers.half_opening - spec.stroke) < 1e-9
    pad = ET.parse(shared_path(ROBOTIQ_URDF)).getroot().find("link[@name='left_inner_finger_pad']/collision/geometry/box")
    assert pad is not None
    assert abs(2 * robotiq.pad_half_width - float(pad.attrib["size"].split()[0])) < 1e-9


def _bar_pick(hold_linkage: bool, monkeypatch: pytest.MonkeyPatch) -> Outcome:
    """Pick a 25 cm, 0.4 kg bar 6 cm off its centre with the Robotiq, as a hammer is picked."""
    from craft_e.runtime.sim.gripper import ParallelGripper

    if not hold_linkage:
        monkeypatch.setattr(ParallelGripper, "hold_linkage", lambda self: None)
    with SimEnv(EnvConfig(gripper=GripperConfig(hand="robotiq_2f85"))) as env:
        x, y = _free_spot(env.reset(EASY), 0.15)
        half, yaw, offset = (0.125, 0.0125, 0.015), 0.3, 0.06
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(half), physicsClientId=env.client)
        bar = p.createMultiBody(0.4, shape, basePosition=[x, y, half[2] + 0.001],
                                baseOrientation=p.getQuaternionFromEuler([0, 0, yaw]),
                                physicsClientId=env.client)
        p.changeDynamics(bar, -1, lateralFriction=0.8, spinningFriction=0.002,
                         physicsClientId=env.client)
        env.step(60)
        at = np.array([x + offset * math.cos(yaw), y + offset * math.sin(yaw), 2 * half[2]])
        grasp = TopDownGrasp(position=at, yaw=yaw + math.pi / 2, width_m=0.025)  # across the bar
        return execute_pick(env, grasp, bar).outcome


def test_robotiq_carries_a_long_bar_held_off_centre(monkeypatch: pytest.MonkeyPatch) -> None:
    """The linkage servo (``ParallelGripper.hold_linkage``) is what keeps the bar in the hand:
    with gear constraints alone the pads' joints drift under the bar's torque and it slides out."""
    assert _bar_pick(True, monkeypatch) is Outcome.SUCCESS
    assert _bar_pick(False, monkeypatch) is Outcome.SLIP_DURING_TRANSPORT
