"""One RGB-D frame with its camera model: what every perception step consumes.

Kept free of any simulator import so the same type carries frames from a real RealSense; the
testbed only fills it. Conventions: OpenCV camera frame (x right, y down, z forward), depth in
metres along the optical axis (0 = no reading), ``cam_to_world`` maps camera-frame points to the
world (robot-base) frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, cached_property

import numpy as np
import numpy.typing as npt

from ..grasp.geometry import CameraIntrinsics


@dataclass(frozen=True)
class Observation:
    """An RGB-D frame; ``seg`` is the simulator's body-id buffer (-1 = nothing), or None."""

    rgb: npt.NDArray[np.uint8]  # [H, W, 3]
    depth: npt.NDArray[np.float32]  # [H, W] metres
    intrinsics: CameraIntrinsics
    cam_to_world: npt.NDArray[np.float64]  # [4, 4]
    seg: npt.NDArray[np.int32] | None = None  # [H, W] oracle labels, simulation only

    def __post_init__(self) -> None:
        h, w = self.depth.shape
        if self.rgb.shape != (h, w, 3):
            raise ValueError(f"rgb {self.rgb.shape} does not match depth {self.depth.shape}")
        if (w, h) != (self.intrinsics.width, self.intrinsics.height):
            raise ValueError(f"image {w}x{h} does not match intrinsics {self.intrinsics}")
        if self.seg is not None and self.seg.shape != (h, w):
            raise ValueError(f"seg {self.seg.shape} does not match depth {self.depth.shape}")

    @property
    def shape(self) -> tuple[int, int]:
        h, w = self.depth.shape
        return h, w

    def points_camera(self) -> npt.NDArray[np.float64]:
        """Per-pixel 3D points in the camera frame, ``[H, W, 3]`` (NaN where depth is invalid).

        Computed once per frame and shared (read-only): segmentation and the grasp checks both
        need them."""
        return self._points_camera

    def points_world(self) -> npt.NDArray[np.float64]:
        """Per-pixel 3D points in the world frame, ``[H, W, 3]`` (NaN where depth is invalid);
        computed once per frame and shared (read-only)."""
        return self._points_world

    def world_z(self) -> npt.NDArray[np.float64]:
        """Per-pixel world height ``[H, W]`` (NaN where depth is invalid): ``points_world()[..., 2]``
        without the other two coordinates, for masks of what stands above a table; computed once
        per frame and shared (read-only)."""
        return self._world_z

    def points_world_at(self, pixels: npt.NDArray[np.intp]) -> npt.NDArray[np.float64]:
        """World points ``[n, 3]`` of the flat pixel indices ``pixels``: ``points_world()`` at
        those pixels, transformed for them alone (or read from it, once computed)."""
        if "_points_world" in self.__dict__:  # the whole frame is already transformed
            done: npt.NDArray[np.float64] = self._points_world.reshape(-1, 3)[pixels]
            return done
        rotation, translation = self.cam_to_world[:3, :3], self.cam_to_world[:3, 3]
        out: npt.NDArray[np.float64] = self._points_camera.reshape(-1, 3)[pixels] @ rotation.T + translation
        return out

    @cached_property
    def _points_camera(self) -> npt.NDArray[np.float64]:
        # ``intrinsics.deproject(pixel grid, z)`` term by term: x = ((u - cx) / fx) * z with the
        # bracket cached per camera (``_ray_factors``), written into one array (the depth
        # straight into its z plane) instead of stacking three: the same IEEE operations in the
        # same order, so the same bits, at about a third of the cost (every frame pays for it)
        h, w = self.shape
        valid = np.isfinite(self.depth) & (self.depth > 0)  # float32 → float64 is exact: the same test
        out = np.empty((h, w, 3))
        z = out[..., 2]
        np.copyto(z, self.depth)
        if not valid.all():
            np.copyto(z, np.nan, where=~valid)
        along_x, along_y = _ray_factors(h, w, self.intrinsics)
        np.multiply(along_x, z, out=out[..., 0])
        np.multiply(along_y, z, out=out[..., 1])
        out.flags.writeable = False
        return out

    @cached_property
    def _points_world(self) -> npt.NDArray[np.float64]:
        rotation, translation = self.cam_to_world[:3, :3], self.cam_to_world[:3, 3]
        out: npt.NDArray[np.float64] = self._points_camera @ rotation.T + translation
        out.flags.writeable = False
        return out

    @cached_property
    def _world_z(self) -> npt.NDArray[np.float64]:
        if "_points_world" in self.__dict__:
            z: npt.NDArray[np.float64] = self._points_world[..., 2]
            return z
        out: npt.NDArray[np.float64] = self._points_camera @ self.cam_to_world[2, :3] + self.cam_to_world[2, 3]
        out.flags.writeable = False
        return out


@cache
def _ray_factors(h: int, w: int, intrinsics: CameraIntrinsics) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """``[H, W]`` ``(u - cx) / fx`` and ``(v - cy) / fy`` per pixel, read-only, one pair per
    camera: what ``CameraIntrinsics.deproject`` computes before multiplying by the depth."""
    v, u = np.mgrid[0:h, 0:w]
    along_x = (u.astype(np.float64) - intrinsics.cx) / intrinsics.fx
    along_y = (v.astype(np.float64) - intrinsics.cy) / intrinsics.fy
    for array in (along_x, along_y):
        array.flags.writeable = False
    return along_x, along_y
