"""Rim grasps of open vessels (issue 10, item 3): bowls and plates are taken by the rim.

Why: people and Cornell-trained networks take a bowl too wide for the hand by its rim, one finger
inside, one outside. The robot's finger check must accept such a grasp on what the camera sees,
and the oracle (the ``oracle`` grasp source, and the static protocol's ground-truth rectangles)
must offer one instead of declaring the object ungraspable. Both are checked on synthetic
geometry with a known answer: a bowl-like ring seen by a camera looking straight down.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from craft_e.runtime.grasp.geometry import CameraIntrinsics, TopDownGrasp
from craft_e.runtime.perception.observation import Observation
from craft_e.runtime.sim.fingers import FingerGeometry, finger_check
from craft_e.runtime.sim.oracle import OracleConfig, rim_grasps

FloatArray = npt.NDArray[np.float64]
CAMERA_HEIGHT = 0.7  # m above the table (z = 0)
TIP_Z = 0.012  # m: finger tips ~3 cm below a 5.5 cm rim, as the executor inserts them


def bowl_height(x: FloatArray, y: FloatArray) -> FloatArray:
    """A 15 cm bowl: 1 cm flat rim band at 5.5 cm, a steep inside down to a 4 mm floor."""
    r = np.hypot(x, y)
    inside = 0.004 + 0.051 * (r / 0.065) ** 4
    return np.where(r > 0.075, 0.0, np.where(r >= 0.065, 0.055, inside))


def solid_height(x: FloatArray, y: FloatArray) -> FloatArray:
    """A 15 cm closed cylinder (a can seen from above): no inside to reach into."""
    return np.where(np.hypot(x, y) <= 0.075, 0.05, 0.0)


def plate_height(x: FloatArray, y: FloatArray) -> FloatArray:
    """A 24 cm plate: 4 mm floor, a lip rising to 2.5 cm over its outer 2 cm."""
    r = np.hypot(x, y)
    lip = 0.004 + 0.021 * np.clip((r - 0.10) / 0.02, 0.0, 1.0)
    return np.where(r > 0.12, 0.0, np.where(r > 0.10, lip, 0.004))


def depth_image(height: object) -> Observation:
    """Render ``height(x, y)`` as a 640x480 depth image from straight above (fixed-point ray
    intersection: rays are near vertical, so a few iterations converge)."""
    intr = CameraIntrinsics.realsense_d435()
    v, u = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float64)
    depth = np.full(u.shape, CAMERA_HEIGHT)
    for _ in range(6):
        x = (u - intr.cx) / intr.fx * depth
        y = -(v - intr.cy) / intr.fy * depth
        depth = CAMERA_HEIGHT - height(x, y)  # type: ignore[operator]
    cam_to_world = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, CAMERA_HEIGHT], [0, 0, 0, 1.0]])
    rgb = np.zeros((intr.height, intr.width, 3), dtype=np.uint8)
    return Observation(rgb, depth.astype(np.float32), intr, cam_to_world)


def surface(height: object) -> FloatArray:
    """The object's surface points as the finger check gets them (its raised depth pixels)."""
    world = depth_image(height).points_world().reshape(-1, 3)
    return world[world[:, 2] > 0.003]


def top_points(height: object, spacing: float = 0.004) -> FloatArray:
    """The top surface as vertical rays sample it (what ``top_surface_points`` returns)."""
    g = np.arange(-0.13, 0.13 + spacing, spacing)
    x, y = np.meshgrid(g, g)
    z = height(x, y)  # type: ignore[operator]
    keep = z > 0
    return np.stack([x[keep], y[keep], z[keep]], axis=1)


def test_the_finger_check_accepts_a_rim_grasp_of_a_bowl() -> None:
    material = surface(bowl_height)
    fingers = FingerGeometry()
    rim = TopDownGrasp(np.array([0.068, 0.0, 0.055]), 0.0, 0.02)  # across the wall, radially
    ok, why = finger_check(material, rim, TIP_Z, fingers)
    assert ok, why
    turned = TopDownGrasp(np.array([0.0, -0.068, 0.055]), math.pi / 2, 0.02)  # another side
    assert finger_check(material, turned, TIP_Z, fingers)[0]
    # centred on the bowl the open fingers (8 cm) reach neither wall: nothing to close on
    middle = TopDownGrasp(np.array([0.0, 0.0, 0.004]), 0.0, 0.08)
    assert not finger_check(material, middle, TIP_Z, fingers)[0]


def test_the_oracle_offers_rim_grasps_of_a_bowl() -> None:
    cfg = OracleConfig()
    grasps = rim_grasps(top_points(bowl_height), cfg, table_z=0.0)
    assert len(grasps) >= 12  # every direction around a round bowl
    material = surface(bowl_height)
    for g in grasps:
        radius = math.hypot(g.position[0], g.position[1])
        assert 0.045 <= radius <= 0.075  # on the wall, not in the middle
        radial = math.atan2(g.position[1], g.position[0])
        assert abs(math.sin(radial - g.yaw)) < 0.2  # closing across the wall
        assert g.width_m <= cfg.max_width - 2 * cfg.side_clearance
        assert g.position[2] == 0.055
        assert finger_check(material, g, TIP_Z, FingerGeometry())[0]  # and the robot agrees


def test_rim_grasps_of_a_plate_but_not_of_a_closed_cylinder() -> None:
    cfg = OracleConfig()
    plate = rim_grasps(top_points(plate_height), cfg, table_z=0.0)
    assert plate and all(0.09 <= math.hypot(g.position[0], g.position[1]) <= 0.12 for g in plate)
    assert rim_grasps(top_points(solid_height), cfg, table_z=0.0) == []


def narrow_cup_height(x: FloatArray, y: FloatArray) -> FloatArray:
    """A 5.8 cm cup, 8 cm tall: 4 mm walls around a 5 cm mouth, a 5 mm floor inside."""
    r = np.hypot(x, y)
    return np.where(r > 0.029, 0.0, np.where(r >= 0.025, 0.08, 0.005))


def test_a_finger_that_would_land_on_the_far_rim_is_rejected() -> None:
    """A rim grasp on a narrow cup puts the inner finger on the far rim (dev: mugs' fingers
    stopped 1-4 cm above the grasp); the span rule alone accepted it, the landing rule does not.
    Taking the same cup whole, or a wide bowl by its rim, lands nothing and stays accepted."""
    material = surface(narrow_cup_height)
    tip_z = 0.08 - 0.03 - 0.0136  # the executor inserts 3 cm below the rim
    rim = TopDownGrasp(np.array([0.027, 0.0, 0.08]), 0.0, 0.02)
    assert finger_check(material, rim, tip_z, FingerGeometry(check_landing=False))[0]
    ok, why = finger_check(material, rim, tip_z, FingerGeometry())
    assert not ok and why == "a finger would land on the object beside the opening"
    whole = TopDownGrasp(np.array([0.0, 0.0, 0.005]), 0.0, 0.06)
    assert finger_check(material, whole, TIP_Z, FingerGeometry()) == (True, "")
    bowl_rim = TopDownGrasp(np.array([0.068, 0.0, 0.055]), 0.0, 0.02)
    assert finger_check(surface(bowl_height), bowl_rim, TIP_Z, FingerGeometry()) == (True, "")
