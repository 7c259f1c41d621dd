"""Grasp rectangles in pixels and top-down gripper poses in the world, through a pinhole camera.

Conventions (the ones GG-CNN and GR-ConvNet were trained with, so network outputs need no
re-interpretation):

* Pixel coordinates are ``(x, y)`` = (column, row), y pointing down, pixel centres at integers.
* ``angle_rad`` is the direction of the gripper's *closing axis* in the image, measured
  counter-clockwise as seen on screen: the axis runs along ``(cos a, -sin a)`` in ``(x, y)``.
  A parallel gripper is symmetric, so angles live in ``[-pi/2, pi/2)``.
* ``width_px`` is the opening along that axis (the original code calls it ``length``, the
  Cornell edge p0→p1); ``length_px`` is the jaw size across it (edge p1→p2). The networks
  predict only the opening; their post-processing sets the jaw size to half of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from scipy import ndimage

FloatArray = npt.NDArray[np.float64]
DepthImage = npt.NDArray[np.float32] | npt.NDArray[np.float64]


def wrap_half_pi(angle: float) -> float:
    """Map an angle to ``[-pi/2, pi/2)``: a two-finger grasp rotated by pi is the same grasp."""
    return float((angle + math.pi / 2) % math.pi - math.pi / 2)


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of an undistorted image (pixels)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def realsense_d435(cls, width: int = 640, height: int = 480) -> CameraIntrinsics:
        """RealSense-D435-like colour intrinsics (fx = fy ≈ 615 at 640×480), scaled to a size.

        Why a default at all: the testbed renders with these numbers, and callers that only have
        an image (no calibration) still need a metric scale for the antipodal sampler.
        """
        sx, sy = width / 640.0, height / 480.0
        return cls(width, height, 615.0 * sx, 615.0 * sy, width / 2.0, height / 2.0)

    @property
    def matrix(self) -> FloatArray:
        """The 3×3 camera matrix K."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    def deproject(self, uv: npt.ArrayLike, z: npt.ArrayLike) -> FloatArray:
        """Pixels ``[..., 2]`` at depths ``[...]`` (metres along the optical axis) → ``[..., 3]``."""
        uv_a = np.asarray(uv, dtype=np.float64)
        z_a = np.asarray(z, dtype=np.float64)
        x = (uv_a[..., 0] - self.cx) / self.fx * z_a
        y = (uv_a[..., 1] - self.cy) / self.fy * z_a
        return np.stack([x, y, np.broadcast_to(z_a, x.shape)], axis=-1)

    def project(self, xyz: npt.ArrayLike) -> FloatArray:
        """Camera-frame points ``[..., 3]`` → pixels ``[..., 2]``."""
        p = np.asarray(xyz, dtype=np.float64)
        return np.stack(
            [p[..., 0] / p[..., 2] * self.fx + self.cx, p[..., 1] / p[..., 2] * self.fy + self.cy],
            axis=-1,
        )


@dataclass(frozen=True)
class Grasp2D:
    """A planar grasp rectangle in image pixels (see the module docstring for conventions).

    ``quality`` is in [0, 1]: the network's (clipped) grasp-quality map value at the centre, or
    the antipodal sampler's score. It feeds ``E_grasp = -log(max quality)``.
    """

    center_xy: tuple[float, float]
    angle_rad: float
    width_px: float
    length_px: float
    quality: float

    @property
    def axis_xy(self) -> tuple[float, float]:
        """Unit vector of the closing axis in ``(x, y)`` pixel coordinates."""
        return (math.cos(self.angle_rad), -math.sin(self.angle_rad))

    def corners(self) -> FloatArray:
        """The four corners ``[4, 2]`` (x, y) in Cornell order: p0→p1 along the closing axis."""
        cx, cy = self.center_xy
        ax, ay = self.axis_xy
        px, py = -ay, ax  # perpendicular (jaw direction)
        hw, hl = self.width_px / 2.0, self.length_px / 2.0
        p0 = (cx - hw * ax, cy - hw * ay)
        p1 = (cx + hw * ax, cy + hw * ay)
        return np.array(
            [
                [p0[0] - hl * px, p0[1] - hl * py],
                [p1[0] - hl * px, p1[1] - hl * py],
                [p1[0] + hl * px, p1[1] + hl * py],
                [p0[0] + hl * px, p0[1] + hl * py],
            ],
            dtype=np.float64,
        )

    @classmethod
    def from_corners(cls, corners: npt.ArrayLike, quality: float = 1.0) -> Grasp2D:
        """Cornell rectangle ``[4, 2]`` (x, y) → grasp; p0→p1 is the closing axis."""
        c = np.asarray(corners, dtype=np.float64).reshape(4, 2)
        d01 = c[1] - c[0]
        d12 = c[2] - c[1]
        center = c.mean(axis=0)
        return cls(
            center_xy=(float(center[0]), float(center[1])),
            angle_rad=wrap_half_pi(math.atan2(-d01[1], d01[0])),
            width_px=float(np.hypot(*d01)),
            length_px=float(np.hypot(*d12)),
            quality=quality,
        )

    def scaled(self, scale: float, offset_xy: tuple[float, float]) -> Grasp2D:
        """Map from a crop resized by ``1/scale`` back to the full image: ``x = off + s·x'``.

        Used with pixel-centre-aware offsets (see ``predict``); angles are unchanged because the
        crops are square and resized isotropically.
        """
        return Grasp2D(
            center_xy=(
                offset_xy[0] + scale * self.center_xy[0],
                offset_xy[1] + scale * self.center_xy[1],
            ),
            angle_rad=self.angle_rad,
            width_px=self.width_px * scale,
            length_px=self.length_px * scale,
            quality=self.quality,
        )


class TopDownGrasp(NamedTuple):
    """A top-down parallel-gripper grasp in the world frame.

    ``position`` is the surface point under the grasp centre (callers add their own approach and
    insertion offsets); ``yaw`` is the direction of the closing axis in the world xy-plane,
    from +x towards +y, in ``[-pi/2, pi/2)``; ``width_m`` is the opening. ``lean`` (rad, 0 for
    every grasp a network or check makes) tilts the hand about its closing axis, the pads still
    level: the simulated robot's last resort when every top-down approach is blocked
    (``sim/relocate.py``).
    """

    position: FloatArray
    yaw: float
    width_m: float
    lean: float = 0.0


def sample_depth(depth: DepthImage, center_xy: tuple[float, float], radius_px: int = 2) -> float:
    """Robust depth at a pixel: the median of the valid values in a small window.

    Single pixels are often holes (0 or NaN) at object edges in real depth images.
    """
    h, w = depth.shape
    u, v = round(center_xy[0]), round(center_xy[1])
    if not (0 <= u < w and 0 <= v < h):
        raise ValueError(f"grasp centre {center_xy} lies outside the {w}x{h} depth image")
    for r in (radius_px, 2 * radius_px + 1, 4 * radius_px + 3):
        win = np.asarray(depth[max(v - r, 0) : v + r + 1, max(u - r, 0) : u + r + 1], np.float64)
        valid = win[np.isfinite(win) & (win > 0)]
        if valid.size:
            return _median(valid)
    raise ValueError(f"no valid depth around pixel {center_xy}")


def _median(values: FloatArray) -> float:
    """``float(np.median(values))`` for finite float64 ``values``, bit for bit: numpy's median is
    the middle order statistic, or the mean of the two (their sum halved), from one partial sort.
    Why: ``np.median``'s argument handling cost ~20 us per call, more than the sort of a 5x5
    window; every grasp the robot considers samples its depth (``tests/test_grasp_geometry.py``)."""
    n = len(values)
    half = n // 2
    if n % 2:
        return float(np.partition(values, half)[half])
    ordered = np.partition(values, (half - 1, half))
    return (float(ordered[half - 1]) + float(ordered[half])) / 2.0


def fill_invalid_depth(depth: DepthImage) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
    """Replace holes (0, negative, NaN, inf) by the nearest valid depth; return the hole mask.

    Holes are common at edges in real sensors; zeros would read as objects right at the lens.
    """
    d = np.asarray(depth, dtype=np.float32)
    invalid: npt.NDArray[np.bool_] = ~np.isfinite(d) | (d <= 0)
    if invalid.all():
        raise ValueError("depth image has no valid pixels (all 0, negative or NaN)")
    if invalid.any():
        _, (ri, ci) = ndimage.distance_transform_edt(invalid, return_indices=True)
        d = d[ri, ci]
    return d, invalid


def _as_transform(cam_to_world: npt.ArrayLike) -> FloatArray:
    T = np.asarray(cam_to_world, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"cam_to_world must be 4x4, got {T.shape}")
    return T


def _ray_plane(origin: FloatArray, direction: FloatArray, plane_z: float) -> FloatArray | None:
    """Intersect a world ray with the horizontal plane ``z = plane_z``; None if the ray is
    parallel to it or points away."""
    if abs(direction[2]) < 1e-9:
        return None
    t = (plane_z - origin[2]) / direction[2]
    return None if t <= 0 else origin + t * direction


def rect_to_pose(
    grasp: Grasp2D,
    depth: DepthImage | float,
    intrinsics: CameraIntrinsics,
    cam_to_world: npt.ArrayLike,
) -> TopDownGrasp:
    """Image rectangle + depth → top-down grasp in the world.

    The centre is deprojected at its depth. The two jaw end points are intersected with the
    horizontal plane through that point, not placed at the same camera depth: a top-down gripper
    closes in a horizontal plane, and for a tilted camera the two differ.
    """
    T = _as_transform(cam_to_world)
    z = sample_depth(depth, grasp.center_xy) if isinstance(depth, np.ndarray) else float(depth)
    if not z > 0:
        raise ValueError(f"depth must be positive, got {z}")
    R, t = T[:3, :3], T[:3, 3]
    # ``intrinsics.deproject`` written out on Python floats (the same IEEE operations, so the
    # same bits, without its array plumbing: four calls were most of this function's time); the
    # matrix products stay numpy's, on the same arrays as before
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    u, v = float(grasp.center_xy[0]), float(grasp.center_xy[1])
    center_c = np.array([(u - cx) / fx * z, (v - cy) / fy * z, z])  # [3] camera frame
    position = R @ center_c + t  # [3] world frame
    ax, ay = grasp.axis_xy
    half = grasp.width_px / 2.0
    ends_uv = ((u - half * ax, v - half * ay), (u + half * ax, v + half * ay))
    hits = [_ray_plane(t, R @ np.array([(eu - cx) / fx * 1.0, (ev - cy) / fy * 1.0, 1.0]), float(position[2]))
            for eu, ev in ends_uv]
    ends: list[FloatArray] = [h for h in hits if h is not None]
    if len(ends) < 2:  # a jaw whose ray misses the plane is taken at the centre's depth instead
        same_depth = np.array([[(eu - cx) / fx * z, (ev - cy) / fy * z, z] for eu, ev in ends_uv]) @ R.T + t
        ends = [same_depth[i] if h is None else h for i, h in enumerate(hits)]
    d = ends[1] - ends[0]
    yaw = wrap_half_pi(math.atan2(float(d[1]), float(d[0])))
    return TopDownGrasp(position=position, yaw=yaw, width_m=float(np.linalg.norm(d)))


def pose_to_rect(
    pose: TopDownGrasp,
    intrinsics: CameraIntrinsics,
    cam_to_world: npt.ArrayLike,
    quality: float = 1.0,
    length_px: float | None = None,
) -> Grasp2D:
    """Top-down grasp in the world → image rectangle (the inverse of ``rect_to_pose``).

    The jaw ends ``position ± width/2 · (cos yaw, sin yaw, 0)`` are projected; the rectangle's
    angle and opening come from them, its centre from the projected position. ``length_px``
    defaults to half the opening, as in the networks' post-processing.
    """
    T = _as_transform(cam_to_world)
    R, t = T[:3, :3], T[:3, 3]
    pos = np.asarray(pose.position, dtype=np.float64)
    axis = np.array([math.cos(pose.yaw), math.sin(pose.yaw), 0.0])
    pts_w = np.stack([pos, pos - axis * pose.width_m / 2, pos + axis * pose.width_m / 2])  # [3, 3]
    pts_c = (pts_w - t) @ R  # [3, 3] camera frame (R^T (p - t))
    if np.any(pts_c[:, 2] <= 0):
        raise ValueError("grasp lies behind the camera")
    uv = intrinsics.project(pts_c)  # [3, 2]
    d = uv[2] - uv[1]
    width_px = float(np.hypot(d[0], d[1]))
    return Grasp2D(
        center_xy=(float(uv[0, 0]), float(uv[0, 1])),
        angle_rad=wrap_half_pi(math.atan2(-float(d[1]), float(d[0]))),
        width_px=width_px,
        length_px=width_px / 2.0 if length_px is None else length_px,
        quality=quality,
    )
