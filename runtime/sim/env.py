"""The testbed environment: one pybullet client holding the CR3, the table and a scene.

The Env owns the client (created here, disconnected on close or when the ``with`` block ends) and
counts simulation steps; everything else receives the client id and passes it on every pybullet
call, so several Envs can live in one process without sharing state. ``reset`` rebuilds the world
from scratch, which is what makes an episode depend only on its scene spec.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from types import TracebackType

import numpy as np
import numpy.typing as npt
import pybullet as p

from ..perception.observation import Observation
from .camera import Camera, render
from .gripper import GripperConfig
from .robot import ArmConfig, CR3Robot
from .scene import Scene, SceneSpec, TableLayout, capture, make_scene


@dataclass(frozen=True)
class PhysicsConfig:
    """Solver settings; the time step is also what turns step counts into seconds."""

    time_step: float = 1.0 / 240.0
    solver_iterations: int = 100
    gravity: float = -9.81
    # Objects whose shipped convex hulls fill an opening (a mug's mouth) collide through the
    # finer meshes of ``collision_meshes``; False loads every asset's shipped hulls.
    fine_collision: bool = True


@dataclass(frozen=True)
class EnvConfig:
    """Everything that defines the testbed; a frozen value so runs can record it."""

    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    arm: ArmConfig = field(default_factory=ArmConfig)
    gripper: GripperConfig = field(default_factory=GripperConfig)
    layout: TableLayout = field(default_factory=TableLayout)
    camera: Camera = field(default_factory=Camera)


class SimEnv:
    """Context manager around one DIRECT pybullet client."""

    def __init__(self, config: EnvConfig | None = None) -> None:
        self.config = config or EnvConfig()
        self.client: int = p.connect(p.DIRECT)
        self.steps = 0
        # Called after every step with the step count; for recording videos, never for control.
        self.step_hook: Callable[[int], None] | None = None
        self._robot: CR3Robot | None = None
        self._scene: Scene | None = None

    def __enter__(self) -> SimEnv:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        if self.client >= 0:
            p.disconnect(physicsClientId=self.client)
            self.client = -1

    @property
    def robot(self) -> CR3Robot:
        if self._robot is None:
            raise RuntimeError("call reset(spec) before using the robot")
        return self._robot

    @property
    def scene(self) -> Scene:
        if self._scene is None:
            raise RuntimeError("call reset(spec) before using the scene")
        return self._scene

    def step(self, n: int = 1) -> None:
        """Advance physics ``n`` steps; the only clock an episode has."""
        for _ in range(n):
            if self._robot is not None:
                self._robot.gripper.hold_linkage()
            p.stepSimulation(physicsClientId=self.client)
            self.steps += 1
            if self.step_hook is not None:
                self.step_hook(self.steps)

    def reset(self, spec: SceneSpec) -> Scene:
        """Empty the world, load robot and table, place and settle the spec's objects."""
        if self.client < 0:
            raise RuntimeError("this SimEnv is closed")
        physics = self.config.physics
        p.resetSimulation(physicsClientId=self.client)
        p.setPhysicsEngineParameter(
            fixedTimeStep=physics.time_step,
            numSolverIterations=physics.solver_iterations,
            deterministicOverlappingPairs=1,
            physicsClientId=self.client,
        )
        p.setGravity(0.0, 0.0, physics.gravity, physicsClientId=self.client)
        self.steps = 0
        arm = dataclasses.replace(self.config.arm, time_step=physics.time_step)
        self._robot = CR3Robot(
            self.client, self.step, config=arm, gripper_config=self.config.gripper
        )
        self._scene = make_scene(spec, self.client, self.config.layout, self.config.camera,
                                 fine_collision=self.config.physics.fine_collision)
        return self._scene

    def capture(self) -> Observation:
        return capture(self.scene)

    def capture_rgb(self, scale: int) -> npt.NDArray[np.uint8]:
        """The scene camera's colour image at ``scale`` x its resolution (``[sH, sW, 3]``), as a
        higher-resolution colour sensor beside the depth camera would give."""
        if scale == 1:
            return capture(self.scene).rgb
        return render(self.client, self.scene.camera.scaled(scale)).rgb
