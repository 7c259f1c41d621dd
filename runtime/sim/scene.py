"""Tabletop scenes for the CR3 testbed: a table, objects at seeded poses, a camera, a drop zone.

The world frame is the robot base frame with the table top at z = 0 (the arm is mounted at table
height beside the table's near edge). A scene is one target plus distractors at random
non-overlapping poses inside the reachable workspace; the objects are dropped a few millimetres
above the table and settled by stepping physics a fixed number of times, so the same seed gives
the same poses bit for bit in a fresh client.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import pybullet as p

from ..perception.observation import Observation
from .assets import object_asset
from .camera import Camera, render
from .collision_meshes import sim_urdf
from .masses import sim_mass
from .placement import (
    Footprint,
    PlacementConfig,
    PlanarPose,
    Rect,
    sample_layout,
)
from .transforms import rpy_to_quat

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SurfaceModel:
    """One friction model for every object.

    The shipped URDFs disagree (YCB 0.5, OCRTOC 0.3, no rolling friction): with those, balls roll
    off and outcomes reflect export quirks rather than grasp quality.
    """

    lateral_friction: float = 0.8
    rolling_friction: float = 0.002
    spinning_friction: float = 0.002


@dataclass(frozen=True)
class TableLayout:
    """Geometry of the testbed, in the robot base frame."""

    # The arm stands on the table top; the table reaches behind it to hold the drop zone.
    table_center: tuple[float, float] = (0.325, 0.0)
    table_half_size: tuple[float, float, float] = (0.475, 0.60, 0.025)
    table_rgba: tuple[float, float, float, float] = (0.62, 0.52, 0.40, 1.0)
    placement: PlacementConfig = field(default_factory=PlacementConfig)
    # Beside the arm's base: reachable up to 0.35 m high (tall objects are released high), and
    # its marker lies outside the overhead camera's view (x > 0.10 at table height), so it never
    # shows up as an ROI. 24 x 22 cm, so an object held off-centre still lands inside.
    drop_zone: Rect = field(default_factory=lambda: Rect(-0.10, 0.14, -0.51, -0.29))
    drop_zone_rgba: tuple[float, float, float, float] = (0.35, 0.65, 0.35, 1.0)
    spawn_clearance: float = 0.003  # m between an object's lowest point and the table at spawn
    settle_steps: int = 240  # always stepped...
    settle_max_steps: int = 1200  # ...then more, in chunks, until everything is at rest
    settle_chunk: int = 60
    rest_linear_speed: float = 0.005  # m/s
    rest_angular_speed: float = 0.05  # rad/s
    surface: SurfaceModel = field(default_factory=SurfaceModel)

    @property
    def table_z(self) -> float:
        return 0.0


@dataclass(frozen=True)
class SceneSpec:
    """What to build: a verb, the object that affords it, the distractors, and a layout seed."""

    verb: str
    target: str
    distractors: tuple[str, ...]
    seed: int

    @property
    def assets(self) -> tuple[str, ...]:
        return (self.target, *self.distractors)


@dataclass(frozen=True)
class PlacedObject:
    """One loaded object: its body, catalog identity, and object-frame bounding box."""

    body_id: int
    asset_id: str
    name: str
    is_target: bool
    local_aabb_min: tuple[float, float, float]  # body frame, metres
    local_aabb_max: tuple[float, float, float]


@dataclass(frozen=True)
class Scene:
    """A built scene inside one pybullet client."""

    client: int
    spec: SceneSpec
    table_id: int
    drop_marker_id: int
    objects: tuple[PlacedObject, ...]
    camera: Camera
    layout: TableLayout

    @property
    def target(self) -> PlacedObject:
        return next(o for o in self.objects if o.is_target)

    @property
    def body_assets(self) -> dict[int, str]:
        """Body id → asset id, for every object in the scene."""
        return {o.body_id: o.asset_id for o in self.objects}

    def object_by_body(self, body_id: int) -> PlacedObject | None:
        return next((o for o in self.objects if o.body_id == body_id), None)

    def pose(self, body_id: int) -> tuple[FloatArray, FloatArray]:
        """Current (position, xyzw quaternion) of a body."""
        pos, quat = p.getBasePositionAndOrientation(body_id, physicsClientId=self.client)
        return np.array(pos, dtype=np.float64), np.array(quat, dtype=np.float64)

    def poses(self) -> dict[int, tuple[FloatArray, FloatArray]]:
        return {o.body_id: self.pose(o.body_id) for o in self.objects}


def _box(
    client: int,
    half: tuple[float, float, float],
    center: tuple[float, float, float],
    rgba: tuple[float, float, float, float],
    collide: bool = True,
) -> int:
    visual = p.createVisualShape(
        p.GEOM_BOX, halfExtents=list(half), rgbaColor=list(rgba), physicsClientId=client
    )
    collision = (
        p.createCollisionShape(p.GEOM_BOX, halfExtents=list(half), physicsClientId=client)
        if collide
        else -1
    )
    return int(
        p.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=collision,
            baseVisualShapeIndex=visual,
            basePosition=list(center),
            physicsClientId=client,
        )
    )


def build_table(client: int, layout: TableLayout) -> tuple[int, int]:
    """Static table (top at z = 0) and a collision-free drop-zone marker; returns their ids."""
    hx, hy, hz = layout.table_half_size
    cx, cy = layout.table_center
    table = _box(client, (hx, hy, hz), (cx, cy, layout.table_z - hz), layout.table_rgba)
    p.changeDynamics(
        table, -1, lateralFriction=layout.surface.lateral_friction, physicsClientId=client
    )
    dz = layout.drop_zone
    visible_x_max = 0.09  # keep the (cosmetic) marker out of the camera's view
    marker_x = (dz.x_min, min(dz.x_max, visible_x_max))
    marker = _box(
        client,
        ((marker_x[1] - marker_x[0]) / 2, (dz.y_max - dz.y_min) / 2, 0.0005),
        ((marker_x[0] + marker_x[1]) / 2, dz.center[1], layout.table_z + 0.0005),
        layout.drop_zone_rgba,
        collide=False,
    )
    return table, marker


def _load_object(
    client: int, asset_id: str, surface: SurfaceModel, fine_collision: bool = True
) -> tuple[int, FloatArray, FloatArray]:
    """Load at the origin, unrotated, to read the object-frame AABB; returns (id, min, max)."""
    asset = object_asset(asset_id)
    body = p.loadURDF(
        str(sim_urdf(asset, fine_collision)),
        basePosition=[0.0, 0.0, 0.0],
        globalScaling=asset.scale,
        physicsClientId=client,
    )
    p.changeDynamics(
        body,
        -1,
        lateralFriction=surface.lateral_friction,
        rollingFriction=surface.rolling_friction,
        spinningFriction=surface.spinning_friction,
        restitution=0.0,
        physicsClientId=client,
    )
    mass = sim_mass(asset)
    if mass is not None:  # the URDF's placeholder gram (masses.py); pybullet rescales the inertia
        p.changeDynamics(body, -1, mass=mass, physicsClientId=client)
    lo, hi = p.getAABB(body, -1, physicsClientId=client)
    return int(body), np.array(lo, dtype=np.float64), np.array(hi, dtype=np.float64)


def make_scene(
    spec: SceneSpec,
    client: int,
    layout: TableLayout | None = None,
    camera: Camera | None = None,
    *,
    fine_collision: bool = True,
) -> Scene:
    """Build the table and the spec's objects in ``client`` and let them settle.

    The client should be freshly reset (``SimEnv.reset`` does this): body ids and the physics
    state, hence the poses, then depend only on the spec. ``fine_collision``: see
    ``PhysicsConfig.fine_collision``.
    """
    layout = layout or TableLayout()
    table, marker = build_table(client, layout)
    loaded = [_load_object(client, a, layout.surface, fine_collision) for a in spec.assets]
    footprints = [
        Footprint(
            center=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2),
            half_size=((hi[0] - lo[0]) / 2, (hi[1] - lo[1]) / 2),
        )
        for _, lo, hi in loaded
    ]
    rng = np.random.default_rng(spec.seed)
    poses = sample_layout(footprints, rng, layout.placement)
    objects: list[PlacedObject] = []
    for i, ((body, lo, hi), footprint, pose) in enumerate(
        zip(loaded, footprints, poses, strict=True)
    ):
        _place(client, body, footprint, pose, float(lo[2]), layout)
        asset = object_asset(spec.assets[i])
        objects.append(
            PlacedObject(
                body_id=body,
                asset_id=asset.asset_id,
                name=asset.name,
                is_target=i == 0,
                local_aabb_min=(float(lo[0]), float(lo[1]), float(lo[2])),
                local_aabb_max=(float(hi[0]), float(hi[1]), float(hi[2])),
            )
        )
    _settle(client, [o.body_id for o in objects], layout)
    return Scene(
        client=client,
        spec=spec,
        table_id=table,
        drop_marker_id=marker,
        objects=tuple(objects),
        camera=camera or Camera(),
        layout=layout,
    )


def _settle(client: int, bodies: list[int], layout: TableLayout) -> None:
    """Step until every object is at rest (a tall bottle may take a second to topple).

    The stopping rule reads only the physics state, so it stays deterministic per seed.
    """
    steps = 0
    while steps < layout.settle_max_steps:
        chunk = layout.settle_steps if steps == 0 else layout.settle_chunk
        for _ in range(chunk):
            p.stepSimulation(physicsClientId=client)
        steps += chunk
        speeds = [p.getBaseVelocity(b, physicsClientId=client) for b in bodies]
        if all(
            np.linalg.norm(lin) < layout.rest_linear_speed
            and np.linalg.norm(ang) < layout.rest_angular_speed
            for lin, ang in speeds
        ):
            return


def _place(
    client: int,
    body: int,
    footprint: Footprint,
    pose: PlanarPose,
    local_min_z: float,
    layout: TableLayout,
) -> None:
    x, y = pose.body_xy(footprint)
    z = layout.table_z - local_min_z + layout.spawn_clearance
    quat = rpy_to_quat(0.0, 0.0, pose.yaw)
    p.resetBasePositionAndOrientation(body, [x, y, z], quat, physicsClientId=client)


def capture(scene: Scene) -> Observation:
    """Render the scene's camera: RGB, metric depth, body-id segmentation, intrinsics, pose."""
    return render(scene.client, scene.camera)
