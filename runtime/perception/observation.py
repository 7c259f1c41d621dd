"""One RGB-D frame with its camera model: what every perception step consumes.

Kept free of any simulator import so the same type carries frames from a real RealSense; the
testbed only fills it. Conventions: OpenCV camera frame (x right, y down, z forward), depth in
metres along the optical axis (0 = no reading), ``cam_to_world`` maps camera-frame points to the
world (robot-base) frame.
"""

from __future__ import annotations

from dataclasses import dataclass

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
        """Per-pixel 3D points in the camera frame, ``[H, W, 3]`` (NaN where depth is invalid)."""
        h, w = self.shape
        v, u = np.mgrid[0:h, 0:w]
        z = self.depth.astype(np.float64)
        z = np.where(np.isfinite(z) & (z > 0), z, np.nan)
        uv = np.stack([u, v], axis=-1).astype(np.float64)
        return self.intrinsics.deproject(uv, z)

    def points_world(self) -> npt.NDArray[np.float64]:
        """Per-pixel 3D points in the world frame, ``[H, W, 3]`` (NaN where depth is invalid)."""
        pts = self.points_camera()
        rotation, translation = self.cam_to_world[:3, :3], self.cam_to_world[:3, 3]
        out: npt.NDArray[np.float64] = pts @ rotation.T + translation
        return out
