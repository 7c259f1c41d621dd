"""A retry policy, reported beside the single-attempt headline (issue 10, item 3).

The paper's Grasp Rate, and ours, is single-attempt: one perception, one choice, one pick. A
real robot that feels its hand close on nothing tries again. This module is that robot: after a
pick whose hand ends *empty* (``missed``: the fingers closed on nothing; ``lift_failed``: the
grip was lost while lifting; ``slip_during_transport``: lost on the way) it opens the hand,
rises, drives home, lets the scene settle, and runs the whole pipeline again on a fresh frame:
segmentation, grasps and their checks, embeddings, grounding with the same verb. The target may
have been pushed or knocked over by the failed attempt; that is the scene the retry sees.

Only failures a robot can sense start a retry: an empty hand (the simulator's finger contacts
stand in for the gripper's width reading). A pick that lifted another body, or put the target
down outside the drop zone, ends the episode, as does a retry that chooses another region than
the target (counted ``wrong_object``, not executed: the same rule as the first attempt). A grasp
within ``same_grasp_distance`` and ``same_grasp_angle_deg`` of one that already failed is not
tried again: the region's next candidate that passes the grasp checks is (``perceive``'s
``exclude``; if there is none, the region has no grasp and grounding passes it over).

The attempts themselves run in ``pipeline.retry_picks`` (they need the whole perception); this
module holds the policy: when to retry, what counts as the same grasp, the way home.

Nothing here changes the first attempt: with retries off the episode records are byte-identical
(``tests/test_retry.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..grasp.geometry import TopDownGrasp
from .env import SimEnv
from .episode import Outcome, PickResult
from .robot import HOME_Q, TcpPose

#: Pick outcomes after which the robot's hand is empty and it knows so.
EMPTY_HAND = frozenset({Outcome.MISSED, Outcome.LIFT_FAILED, Outcome.SLIP_DURING_TRANSPORT})


@dataclass(frozen=True)
class RetryConfig:
    """How many more attempts after the first, and what counts as the same grasp again."""

    retries: int = 0  # 0: single attempt (the headline protocol)
    same_grasp_distance: float = 0.02  # m between grasp centres
    same_grasp_angle_deg: float = 20.0  # between closing axes (modulo 180°)
    rise: float = 0.10  # m straight up with the hand open, before driving home
    settle_steps: int = 120  # physics steps at home before the new frame

    def __post_init__(self) -> None:
        if self.retries < 0:
            raise ValueError(f"retries {self.retries} must be >= 0")


@dataclass(frozen=True)
class Attempt:
    """One retry: what grounding chose on the new frame and how the pick ended."""

    chosen_roi: int | None
    detect: bool
    failure: str  # a ``pipeline.Failure`` value
    pick_detail: str = ""
    grasp_quality: float | None = None

    def to_dict(self) -> dict[str, object]:
        return {"chosen_roi": self.chosen_roi, "detect": self.detect, "failure": self.failure,
                "pick_detail": self.pick_detail,
                "grasp_quality": None if self.grasp_quality is None else round(self.grasp_quality, 6)}


def hand_empty(pick: PickResult) -> bool:
    """Did the pick end with nothing in the hand (a failure the robot senses)?"""
    return pick.outcome in EMPTY_HAND


def same_grasp(a: TopDownGrasp, b: TopDownGrasp, cfg: RetryConfig) -> bool:
    """Is ``a`` the grasp ``b`` again: centres close and closing axes nearly parallel?"""
    gap = float(np.linalg.norm(np.asarray(a.position[:2]) - np.asarray(b.position[:2])))
    turn = abs((a.yaw - b.yaw + math.pi / 2) % math.pi - math.pi / 2)
    return gap <= cfg.same_grasp_distance and math.degrees(turn) <= cfg.same_grasp_angle_deg


def rising_lean(tcp: TcpPose) -> float:
    """The lean a hand keeps as it rises after a miss: a leaned pick's (relocation's last resort,
    20°) rises leaned, not turning its wrist on the way up; a top-down pick's measured lean is
    only IK's tolerance (under 2°), and it rises exactly top-down (0.0), as before leans existed."""
    lean = tcp.lean
    return lean if abs(lean) > math.radians(5.0) else 0.0


def return_home(env: SimEnv, cfg: RetryConfig) -> None:
    """Open the hand, rise straight up (when reachable), drive to home, settle: physical moves,
    so whatever the hand touches on the way is pushed as it would be."""
    robot = env.robot
    robot.hold()
    robot.gripper.open()
    tcp = robot.tcp_pose()
    robot.move_linear(tuple(float(v) for v in tcp.position + np.array([0.0, 0.0, cfg.rise])), tcp.yaw,
                      rising_lean(tcp))
    robot.follow([HOME_Q])
    env.step(cfg.settle_steps)
    robot.reset_home()  # the settled arm is at home to ~1e-4 rad; make the frame's start exact


def succeeded(first_success: bool, attempts: Sequence[Attempt]) -> bool:
    """Success within the attempts: the first pick, or the last retry."""
    return first_success or (bool(attempts) and attempts[-1].failure == "success")
