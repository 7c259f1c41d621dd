"""Probe: where the pads touch a flat object when they close, at two finger-tip clearances.

Why: a pick that "lost the grip while lifting (target rose 0.000 m)" says nothing about the
contact. This executes the two wrench grasps of ``tests/test_flat_object_picks.py`` (GR-ConvNet's
chosen grasps of dev episodes ``tighten/adjustable_wrench/0`` and ``/2``) with the default pick,
at each ``--clearance``, and prints every pad contact on the target right after the close: its
height above the table and how far its normal tilts up from horizontal (0° = a squeeze across
the object, 90° = a pad pressing down on its top), with the pick's outcome.

Run: ``.venv/bin/python benchmarks/probe_pad_contacts.py [--clearance 0.004 --clearance 0.002]``
(~15 s).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import pybullet as p

from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.episode import PickConfig, execute_pick

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_flat_object_picks import NETWORK_GRASPS  # the grasps the test pins


def pad_contacts(env: SimEnv, body: int) -> list[tuple[float, float, float]]:
    """(height above the table in mm, normal tilt up from horizontal in degrees, normal force N)
    of every contact between the hand's finger links and ``body``."""
    gripper = env.robot.gripper
    out: list[tuple[float, float, float]] = []
    for link in (*gripper.left_links, *gripper.right_links):
        for c in p.getContactPoints(bodyA=gripper.body_id, bodyB=body, linkIndexA=link,
                                    physicsClientId=env.client):
            normal = np.asarray(c[7], dtype=np.float64)  # on the object, towards the finger
            tilt = math.degrees(math.asin(min(1.0, abs(float(normal[2])))))
            out.append((1000.0 * (float(c[6][2]) - env.scene.layout.table_z), tilt, float(c[9])))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--clearance", type=float, action="append", default=None,
                        help="PickConfig.table_clearance in metres (repeatable; default 0.004 and 0.002)")
    args = parser.parse_args()
    with SimEnv() as env:
        for spec, grasp, _ in NETWORK_GRASPS:
            for clearance in args.clearance or [0.004, 0.002]:
                scene = env.reset(spec)
                target = scene.target.body_id
                seen: list[tuple[float, float, float]] = []
                close = env.robot.gripper.close

                def close_and_look(close: object = close, target: int = target,
                                   seen: list[tuple[float, float, float]] = seen) -> None:
                    close()  # type: ignore[operator]
                    seen.extend(pad_contacts(env, target))

                env.robot.gripper.close = close_and_look  # type: ignore[method-assign]
                try:
                    result = execute_pick(env, grasp, target, PickConfig(table_clearance=clearance))
                finally:
                    del env.robot.gripper.close  # the class's method again
                pressing = [c for c in seen if c[2] > 1.0]
                print(f"{spec.seed} at {1000 * clearance:g} mm: {result.outcome.value}; pad contacts "
                      f"(height mm / tilt ° / N): "
                      + ", ".join(f"{h:.1f}/{t:.0f}/{f:.0f}" for h, t, f in pressing))


if __name__ == "__main__":
    main()
