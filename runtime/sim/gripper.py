"""The gripper on the CR3 flange: open, close, measure the opening, ask what is held.

One driver for both hands of ``hands.py``. The Franka hand's two prismatic fingers are commanded
to the same target with the same force. The Robotiq 2F-85 is a linkage: one driven joint
per finger and joints that follow it; pybullet ignores URDF ``mimic`` tags, so each follower is
tied to its driver by a ``JOINT_GEAR`` constraint. A gear constraint couples velocities only: under
a held load its position error grows unchecked (a hammer carried by the Robotiq: the pads' joints
drifted 0.3 rad from the linkage's, the pads tilted and the hammer slid out). So before every
physics step each follower is also servoed to ``multiplier`` x its driver's position
(``hold_linkage``), as the real linkage's rigid bars hold it.
The opening is measured between the pads, not read from joint values, so it means the same for
both hands. Every action runs a fixed number of simulation steps so episodes are deterministic.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import pybullet as p

from .hands import DEFAULT_HAND, HandName, HandSpec, hand_spec


@dataclass(frozen=True)
class GripperConfig:
    """Which hand, and how it is driven; ``None`` fields take the hand's defaults.

    Robotiq force, measured on fixed 20 and 50 mm boxes (``tests/test_sim_gripper.py``): 15-27 N
    normal force per pad, the low end of the real 2F-85's 20-235 N. In this model the pad force is
    set by the closing speed, not by the driven joints' effort: pybullet builds a joint motor's
    effort from its velocity target over a fixed number of solver iterations, and the light
    Robotiq links get ~1.4-1.8 N·m from the 2 rad/s target (4, 8 and 16 N·m gave the same
    forces). So ``force`` bounds the Robotiq's squeeze without setting it
    (``docs/results/sim_execution.md``).
    """

    hand: HandName = DEFAULT_HAND
    force: float | None = None
    max_speed: float | None = None
    open_steps: int = 120
    close_steps: int = 120
    min_held_width: float = 0.002  # narrower than this means the fingers met: nothing is held
    gear_force: float = 500.0  # N·m a mimic constraint may exert to keep the linkage coupled
    # The follower servo of ``hold_linkage``: effort (N·m) and position gain (1 = close the whole
    # error in one step). The force never binds on held objects (20 and 100 N·m gave the same
    # motion on a carried hammer); the gain is what removes the drift.
    linkage_force: float = 100.0
    linkage_gain: float = 1.0

    @property
    def spec(self) -> HandSpec:
        return hand_spec(self.hand)


@dataclass(frozen=True)
class FingerContacts:
    """Bodies each finger touches (robot excluded), for grasp checks and diagnostics."""

    left: frozenset[int]
    right: frozenset[int]

    @property
    def pinched(self) -> frozenset[int]:
        return self.left & self.right


class ParallelGripper:
    """A parallel gripper of one CR3 body, driven with position control."""

    def __init__(
        self,
        client: int,
        body_id: int,
        joints: Mapping[str, int],
        step: Callable[[int], None],
        config: GripperConfig | None = None,
    ) -> None:
        """``joints`` maps every joint name of the body to its index (link index = joint index)."""
        self.client = client
        self.body_id = body_id
        self.config = config or GripperConfig()
        self.hand = self.config.spec
        self._step = step
        hand = self.hand
        self.finger_joints = [joints[n] for n in hand.driven_joints]
        self.left_links = [self._link(joints, n) for n in hand.left_links]
        self.right_links = [self._link(joints, n) for n in hand.right_links]
        self.pads = (self._link(joints, hand.left_pad), self._link(joints, hand.right_pad))
        self.force = self.config.force if self.config.force is not None else hand.force
        self.max_speed = self.config.max_speed if self.config.max_speed is not None else hand.max_speed
        self._mimics = [(joints[m.joint], joints[m.driver], m.multiplier) for m in hand.mimics]
        self._couple()
        for link in (*self.left_links, *self.right_links):
            p.changeDynamics(
                body_id, link,
                lateralFriction=hand.pad_lateral_friction,
                spinningFriction=hand.pad_spinning_friction,
                rollingFriction=hand.pad_rolling_friction,
                physicsClientId=client,
            )

    def _link(self, joints: Mapping[str, int], link: str) -> int:
        """Index of ``link``: that of the joint whose child it is."""
        for j in joints.values():
            info = p.getJointInfo(self.body_id, j, physicsClientId=self.client)
            if info[12].decode() == link:
                return j
        raise KeyError(f"link {link!r} not in the robot")

    def _couple(self) -> None:
        """Gear constraints: each follower turns ``multiplier`` times its driver."""
        for joint, driver, multiplier in self._mimics:
            p.setJointMotorControl2(self.body_id, joint, p.VELOCITY_CONTROL, force=0.0,
                                    physicsClientId=self.client)
            c = p.createConstraint(
                self.body_id, driver, self.body_id, joint,
                jointType=p.JOINT_GEAR, jointAxis=[1, 0, 0],
                parentFramePosition=[0, 0, 0], childFramePosition=[0, 0, 0],
                physicsClientId=self.client,
            )
            p.changeConstraint(c, gearRatio=-multiplier, maxForce=self.config.gear_force, erp=1.0,
                               physicsClientId=self.client)

    def hold_linkage(self) -> None:
        """Servo every follower to ``multiplier`` x its driver's current position.

        ``SimEnv.step`` calls it before each physics step; a hand without followers (the Franka
        hand) does nothing, so its episodes are unchanged.
        """
        for joint, driver, multiplier in self._mimics:
            q = p.getJointState(self.body_id, driver, physicsClientId=self.client)[0]
            p.setJointMotorControl2(
                self.body_id, joint, p.POSITION_CONTROL, targetPosition=multiplier * q,
                force=self.config.linkage_force, positionGain=self.config.linkage_gain,
                physicsClientId=self.client,
            )

    def _command(self, q: float, force: float | None = None) -> None:
        for joint in self.finger_joints:
            p.setJointMotorControl2(
                self.body_id,
                joint,
                p.POSITION_CONTROL,
                targetPosition=q,
                force=self.force if force is None else force,
                maxVelocity=self.max_speed,
                physicsClientId=self.client,
            )

    def reset_open(self) -> None:
        """Teleport the fingers open (scene setup only; not a physical motion)."""
        q = self.hand.open_q
        for joint in self.finger_joints:
            p.resetJointState(self.body_id, joint, q, physicsClientId=self.client)
        for joint, _, multiplier in self._mimics:
            p.resetJointState(self.body_id, joint, q * multiplier, physicsClientId=self.client)
        self._command(q)

    def open(self) -> None:
        self._command(self.hand.open_q)
        self._step(self.config.open_steps)

    def close(self, gentle: bool = False) -> None:
        """Close until blocked; the target stays at the closed limit so the force keeps squeezing.
        ``gentle``: with the hand's gentle force (``HandSpec.gentle_force``) until it opens, where
        it has one."""
        self._command(self.hand.closed_q, self.hand.gentle_force if gentle else None)
        self._step(self.config.close_steps)

    def width(self) -> float:
        """Current gap between the pads' inner faces (m), measured along the closing axis."""
        states = [p.getLinkState(self.body_id, link, computeForwardKinematics=True,
                                 physicsClientId=self.client) for link in self.pads]
        rotation = np.array(p.getMatrixFromQuaternion(states[0][5]), dtype=np.float64).reshape(3, 3)
        axis = rotation[:, 1]  # both hands close along their base's (and pads') y axis
        gap = abs(float((np.array(states[0][4]) - np.array(states[1][4])) @ axis))
        return max(0.0, gap - self.hand.pad_thickness)

    def contacts(self) -> FingerContacts:
        found: list[frozenset[int]] = []
        for links in (self.left_links, self.right_links):
            bodies: set[int] = set()
            for link in links:
                points = p.getContactPoints(bodyA=self.body_id, linkIndexA=link,
                                            physicsClientId=self.client)
                bodies.update(int(c[2]) for c in points if c[2] != self.body_id)
            found.append(frozenset(bodies))
        return FingerContacts(found[0], found[1])

    def pad_forces(self, body: int) -> tuple[float, float]:
        """Total normal force (N) of each finger on ``body``; for tests and diagnostics."""
        totals: list[float] = []
        for links in (self.left_links, self.right_links):
            total = 0.0
            for link in links:
                for c in p.getContactPoints(bodyA=self.body_id, bodyB=body, linkIndexA=link,
                                            physicsClientId=self.client):
                    total += float(c[9])
            totals.append(total)
        return totals[0], totals[1]

    def check_grasp(self, ignore: frozenset[int] = frozenset()) -> int | None:
        """Body pinched between both fingers, or None.

        Both fingers must touch it (one-sided contact is a push, not a grasp) and the fingers must
        not have met. ``ignore`` holds static bodies (the table) that fingertips may graze. With
        several candidates the lowest id wins, for determinism.
        """
        if self.width() < self.config.min_held_width:
            return None
        pinched = self.contacts().pinched - ignore
        return min(pinched) if pinched else None
