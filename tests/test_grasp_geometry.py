"""Rectangle ↔ top-down pose through pinhole intrinsics and depth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from craft_e.runtime.grasp.geometry import (
    CameraIntrinsics,
    Grasp2D,
    TopDownGrasp,
    fill_invalid_depth,
    pose_to_rect,
    rect_to_pose,
    sample_depth,
    wrap_half_pi,
)
from craft_e.runtime.grasp.metrics import angle_difference

INTR = CameraIntrinsics.realsense_d435()
# camera 0.5 m above the table origin + (0.4, 0), looking straight down; image x = world x
TOP_DOWN = np.array(
    [[1.0, 0.0, 0.0, 0.4], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.5], [0.0, 0.0, 0.0, 1.0]]
)


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """cam_to_world for a camera at ``eye`` looking at ``target`` (image y towards world -z)."""
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, np.array([0.0, 0.0, 1.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def test_d435_intrinsics() -> None:
    assert CameraIntrinsics(640, 480, 615.0, 615.0, 320.0, 240.0) == INTR
    half = CameraIntrinsics.realsense_d435(320, 240)
    assert (half.fx, half.cx, half.cy) == (307.5, 160.0, 120.0)
    pts = np.array([[0.1, -0.05, 0.7], [0.0, 0.0, 0.3]])
    assert np.allclose(INTR.deproject(INTR.project(pts), pts[:, 2]), pts)
    with pytest.raises(AttributeError):
        INTR.fx = 1.0  # type: ignore[misc]


def test_rect_to_pose_top_down() -> None:
    depth = np.full((480, 640), 0.5, dtype=np.float32)
    g = Grasp2D((320.0 + 61.5, 240.0), 0.0, 123.0, 60.0, 0.9)
    pose = rect_to_pose(g, depth, INTR, TOP_DOWN)
    assert pose.position == pytest.approx([0.45, 0.0, 0.0], abs=1e-9)
    assert pose.yaw == pytest.approx(0.0, abs=1e-9)
    assert pose.width_m == pytest.approx(0.1)
    up = Grasp2D((320.0, 240.0), math.pi / 2, 123.0, 60.0, 0.9)  # closing axis up the image
    assert angle_difference(rect_to_pose(up, depth, INTR, TOP_DOWN).yaw, math.pi / 2) < 1e-9
    diag = Grasp2D((320.0, 240.0), math.radians(30.0), 123.0, 60.0, 0.9)  # y flips: yaw = +30°
    assert rect_to_pose(diag, 0.5, INTR, TOP_DOWN).yaw == pytest.approx(math.radians(30.0))


def test_round_trip_top_down_is_exact() -> None:
    depth = np.full((480, 640), 0.5, dtype=np.float32)
    g = Grasp2D((250.0, 300.0), math.radians(-40.0), 80.0, 40.0, 0.6)
    back = pose_to_rect(rect_to_pose(g, depth, INTR, TOP_DOWN), INTR, TOP_DOWN, quality=0.6)
    assert back.center_xy == pytest.approx(g.center_xy)
    assert back.angle_rad == pytest.approx(g.angle_rad)
    assert back.width_px == pytest.approx(g.width_px)
    assert back.length_px == pytest.approx(40.0)


def test_round_trip_tilted_camera() -> None:
    T = _look_at(np.array([0.45, -0.45, 0.55]), np.array([0.45, 0.0, 0.0]))
    R, t = T[:3, :3], T[:3, 3]
    for angle_deg in (-60.0, 0.0, 45.0, 80.0):
        g = Grasp2D((300.0, 260.0), math.radians(angle_deg), 70.0, 35.0, 1.0)
        ray = R @ INTR.deproject(g.center_xy, 1.0)
        z = -t[2] / ray[2]  # depth along the optical axis where the ray meets the table z = 0
        pose = rect_to_pose(g, float(z), INTR, T)
        assert pose.position[2] == pytest.approx(0.0, abs=1e-9)
        back = pose_to_rect(pose, INTR, T)
        assert back.center_xy == pytest.approx(g.center_xy)
        assert math.degrees(angle_difference(back.angle_rad, g.angle_rad)) < 1.0
        assert back.width_px == pytest.approx(g.width_px, rel=0.02)


def test_pose_to_rect_projects_world_grasp() -> None:
    pose = TopDownGrasp(position=np.array([0.4, 0.0, 0.0]), yaw=0.0, width_m=0.05)
    g = pose_to_rect(pose, INTR, TOP_DOWN)
    assert g.center_xy == pytest.approx((320.0, 240.0))
    assert g.width_px == pytest.approx(61.5)
    assert g.angle_rad == pytest.approx(0.0)


def test_depth_helpers_tolerate_holes() -> None:
    depth = np.full((50, 60), 0.8, dtype=np.float32)
    depth[20:30, 20:30] = 0.0
    depth[25, 25] = np.nan
    assert sample_depth(depth, (25.0, 25.0)) == pytest.approx(0.8)
    filled, holes = fill_invalid_depth(depth)
    assert holes.sum() == 100 and np.all(filled == pytest.approx(0.8))
    with pytest.raises(ValueError, match="outside"):
        sample_depth(depth, (100.0, 10.0))
    assert wrap_half_pi(math.pi / 2) == pytest.approx(-math.pi / 2)


def _reference_rect_to_pose(grasp: Grasp2D, depth: np.ndarray | float, intrinsics: CameraIntrinsics,
                            cam_to_world: np.ndarray) -> TopDownGrasp:
    """``rect_to_pose`` as it was before its deprojections moved to Python floats (numpy's
    ``deproject`` and ``np.median``): the oracle the faster form must equal bit for bit."""
    T = np.asarray(cam_to_world, dtype=np.float64)
    if isinstance(depth, np.ndarray):
        u, v = round(grasp.center_xy[0]), round(grasp.center_xy[1])
        z = math.nan
        for r in (2, 5, 11):
            win = np.asarray(depth[max(v - r, 0) : v + r + 1, max(u - r, 0) : u + r + 1], np.float64)
            valid = win[np.isfinite(win) & (win > 0)]
            if valid.size:
                z = float(np.median(valid))
                break
        if math.isnan(z):
            raise ValueError("no valid depth")
    else:
        z = float(depth)
    R, t = T[:3, :3], T[:3, 3]
    position = R @ intrinsics.deproject(grasp.center_xy, z) + t
    ax, ay = grasp.axis_xy
    half = grasp.width_px / 2.0
    ends_uv = np.array([[grasp.center_xy[0] - half * ax, grasp.center_xy[1] - half * ay],
                        [grasp.center_xy[0] + half * ax, grasp.center_xy[1] + half * ay]])
    ends_same_depth = intrinsics.deproject(ends_uv, np.full(2, z)) @ R.T + t
    ends = []
    for uv, fallback in zip(ends_uv, ends_same_depth, strict=True):
        direction = R @ intrinsics.deproject(uv, 1.0)
        if abs(direction[2]) < 1e-9:
            ends.append(fallback)
            continue
        along = (float(position[2]) - t[2]) / direction[2]
        ends.append(fallback if along <= 0 else t + along * direction)
    d = ends[1] - ends[0]
    yaw = wrap_half_pi(math.atan2(float(d[1]), float(d[0])))
    return TopDownGrasp(position=position, yaw=yaw, width_m=float(np.linalg.norm(d)))


def test_rect_to_pose_equals_its_numpy_form_bit_for_bit() -> None:
    """Grasp poses feed the finger checks and the IK targets of every pick, so the faster form
    must not move a bit: random rectangles on a noisy depth image with holes (odd and even counts
    of valid pixels in the median's window), under a tilted and the top-down camera, plus rays
    that miss the plane (the fallback) and a constant depth."""
    rng = np.random.default_rng(11)
    depth = (0.6 + rng.normal(scale=0.02, size=(120, 160))).astype(np.float32)
    depth[rng.random(depth.shape) < 0.2] = 0.0
    depth[rng.random(depth.shape) < 0.05] = np.nan
    intrinsics = CameraIntrinsics.realsense_d435(160, 120)
    cameras = [TOP_DOWN, _look_at(np.array([0.45, -0.45, 0.55]), np.array([0.45, 0.0, 0.0]))]
    for i in range(400):
        grasp = Grasp2D((float(rng.uniform(0, 159)), float(rng.uniform(0, 119))), float(rng.uniform(-1.6, 1.6)),
                        float(rng.uniform(1, 300)), 10.0, 0.5)
        camera = cameras[i % 2]
        for source in (depth, float(rng.uniform(0.3, 0.9))):
            ours, reference = rect_to_pose(grasp, source, intrinsics, camera), _reference_rect_to_pose(
                grasp, source, intrinsics, camera)
            assert np.array_equal(ours.position, reference.position)
            assert ours.yaw == reference.yaw and ours.width_m == reference.width_m
    # a camera looking along the table (optical axis = world x, image y = world down): the centre
    # lies below the horizon and the upper jaw's ray points up, away from the grasp's plane, so
    # that end is the fallback (the jaw at the centre's depth)
    level = np.eye(4)
    level[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    level[:3, 3] = (0.0, 0.0, 0.3)
    grasp = Grasp2D((80.0, 70.0), math.pi / 2, 100.0, 10.0, 0.5)
    ours, reference = rect_to_pose(grasp, 0.5, intrinsics, level), _reference_rect_to_pose(grasp, 0.5, intrinsics, level)
    assert np.array_equal(ours.position, reference.position) and ours.width_m == reference.width_m
    ray = level[:3, :3] @ intrinsics.deproject((80.0, 20.0), 1.0)  # the upper jaw's ray
    assert ray[2] > 0 and (ours.position[2] - level[2, 3]) / ray[2] <= 0  # it takes the fallback
