"""The Franka hand on the CR3 flange: open, close, and ask whether something is held.

pybullet ignores URDF ``mimic`` tags, so both fingers are commanded to the same target with the
same force; that keeps the grasp centred without a gear constraint. Every action runs a fixed
number of simulation steps so episodes are deterministic per seed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import pybullet as p


@dataclass(frozen=True)
class GripperConfig:
    """Finger limits and forces; defaults follow the Franka hand (8 cm stroke, 20 N rated)."""

    max_finger: float = 0.04  # m of travel per finger (opening = 2x)
    force: float = 40.0  # N per finger; above the rated 20 N so heavy bottles do not slip
    max_speed: float = 0.2  # m/s per finger
    open_steps: int = 60
    close_steps: int = 120
    min_held_width: float = 0.002  # narrower than this means the fingers met: nothing is held


@dataclass(frozen=True)
class FingerContacts:
    """Bodies each finger touches (robot excluded), for grasp checks and diagnostics."""

    left: frozenset[int]
    right: frozenset[int]

    @property
    def pinched(self) -> frozenset[int]:
        return self.left & self.right


class ParallelGripper:
    """Two prismatic fingers on one body, driven with position control."""

    def __init__(
        self,
        client: int,
        body_id: int,
        finger_joints: Sequence[int],
        step: Callable[[int], None],
        config: GripperConfig | None = None,
    ) -> None:
        if len(finger_joints) != 2:
            raise ValueError(f"a parallel gripper needs two finger joints, got {finger_joints}")
        self.client = client
        self.body_id = body_id
        self.finger_joints = list(finger_joints)
        self.config = config or GripperConfig()
        self._step = step

    def _command(self, finger: float) -> None:
        for joint in self.finger_joints:
            p.setJointMotorControl2(
                self.body_id,
                joint,
                p.POSITION_CONTROL,
                targetPosition=finger,
                force=self.config.force,
                maxVelocity=self.config.max_speed,
                physicsClientId=self.client,
            )

    def reset_open(self) -> None:
        """Teleport the fingers open (scene setup only; not a physical motion)."""
        for joint in self.finger_joints:
            p.resetJointState(
                self.body_id, joint, self.config.max_finger, physicsClientId=self.client
            )
        self._command(self.config.max_finger)

    def open(self) -> None:
        self._command(self.config.max_finger)
        self._step(self.config.open_steps)

    def close(self) -> None:
        """Close until blocked; the position target stays at 0 so the force keeps squeezing."""
        self._command(0.0)
        self._step(self.config.close_steps)

    def width(self) -> float:
        """Current opening between the fingers (m)."""
        states = p.getJointStates(self.body_id, self.finger_joints, physicsClientId=self.client)
        return float(sum(s[0] for s in states))

    def contacts(self) -> FingerContacts:
        found: list[frozenset[int]] = []
        for joint in self.finger_joints:
            points = p.getContactPoints(
                bodyA=self.body_id, linkIndexA=joint, physicsClientId=self.client
            )
            found.append(frozenset(int(c[2]) for c in points if c[2] != self.body_id))
        return FingerContacts(found[0], found[1])

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
