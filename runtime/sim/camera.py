"""A pinhole RGB-D camera in pybullet, rendered with TinyRenderer.

The OpenGL projection is built from the intrinsics (fx, fy, cx, cy) rather than from a field of
view, so the rendered pixels obey exactly the model the grasp code deprojects with. TinyRenderer
runs in DIRECT mode without a display or GPU and gives identical images on every machine.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import pybullet as p

from ..grasp.geometry import CameraIntrinsics
from ..perception.observation import Observation
from .transforms import look_at

FloatArray = npt.NDArray[np.float64]
_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])  # flip y and z: OpenGL camera → OpenCV camera


@dataclass(frozen=True)
class Camera:
    """Intrinsics plus a look-at pose; ``near``/``far`` bound the depth buffer (metres)."""

    intrinsics: CameraIntrinsics = field(default_factory=CameraIntrinsics.realsense_d435)
    eye: tuple[float, float, float] = (0.375, 0.0, 0.70)
    target: tuple[float, float, float] = (0.375, 0.0, 0.0)
    up: tuple[float, float, float] = (1.0, 0.0, 0.0)  # image top points away from the robot
    near: float = 0.05
    far: float = 3.0

    def scaled(self, factor: int) -> Camera:
        """The same camera with every pixel split into ``factor`` x ``factor`` (a sharper colour
        image of the same view; box coordinates scale by ``factor``)."""
        k = self.intrinsics
        if factor == 1:
            return self
        hires = CameraIntrinsics(k.width * factor, k.height * factor, k.fx * factor, k.fy * factor,
                                 (k.cx + 0.5) * factor - 0.5, (k.cy + 0.5) * factor - 0.5)
        return dataclasses.replace(self, intrinsics=hires)

    def view_matrix(self) -> list[float]:
        """Column-major OpenGL view matrix (pybullet's layout)."""
        return [float(v) for v in look_at(self.eye, self.target, self.up).T.reshape(-1)]

    def projection_matrix(self) -> list[float]:
        """Column-major OpenGL projection for the intrinsics (pybullet's layout).

        TinyRenderer samples column i at window x = i but flips rows as r = H - y, so the
        principal point is shifted by one row to keep pixel centres on integer coordinates
        (measured: rendered spheres land within 0.05 px of their projection).
        """
        k = self.intrinsics
        w, h, n, f = k.width, k.height, self.near, self.far
        cx, cy = k.cx, k.cy + 1.0
        m = np.array(
            [
                [2 * k.fx / w, 0.0, 1 - 2 * cx / w, 0.0],
                [0.0, 2 * k.fy / h, 2 * cy / h - 1, 0.0],
                [0.0, 0.0, -(f + n) / (f - n), -2 * f * n / (f - n)],
                [0.0, 0.0, -1.0, 0.0],
            ]
        )
        return [float(v) for v in m.T.reshape(-1)]

    def cam_to_world(self) -> FloatArray:
        """OpenCV-convention camera pose in the world (4x4)."""
        view = look_at(self.eye, self.target, self.up)
        pose = np.asarray(np.linalg.inv(view) @ _GL_TO_CV, dtype=np.float64)
        return pose

    def metric_depth(self, buffer: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """Non-linear z-buffer → metres along the optical axis; far plane → 0 (no reading)."""
        d = buffer.astype(np.float64)
        z = self.far * self.near / (self.far - (self.far - self.near) * d)
        z[d >= 1.0] = 0.0
        return z.astype(np.float32)


@dataclass(frozen=True)
class Lighting:
    """TinyRenderer's single directional light; shadows off (they cost time and fake edges)."""

    direction: tuple[float, float, float] = (0.3, 0.2, 1.0)
    ambient: float = 0.6
    diffuse: float = 0.45
    specular: float = 0.05


def render(client: int, camera: Camera, lighting: Lighting | None = None) -> Observation:
    """Render RGB, metric depth and the body-id segmentation buffer."""
    light = lighting or Lighting()
    k = camera.intrinsics
    _, _, rgba, depth, seg = p.getCameraImage(
        k.width,
        k.height,
        viewMatrix=camera.view_matrix(),
        projectionMatrix=camera.projection_matrix(),
        renderer=p.ER_TINY_RENDERER,
        shadow=0,
        lightDirection=list(light.direction),
        lightAmbientCoeff=light.ambient,
        lightDiffuseCoeff=light.diffuse,
        lightSpecularCoeff=light.specular,
        physicsClientId=client,
    )
    rgb = np.asarray(rgba, dtype=np.uint8).reshape(k.height, k.width, 4)[..., :3].copy()
    buffer = np.asarray(depth, dtype=np.float32).reshape(k.height, k.width)
    labels = np.asarray(seg, dtype=np.int32).reshape(k.height, k.width)
    return Observation(
        rgb=rgb,
        depth=camera.metric_depth(buffer),
        intrinsics=k,
        cam_to_world=camera.cam_to_world(),
        seg=labels,
    )
