"""Scenes: catalog, seeded non-overlapping placement, determinism, and the camera model."""

from __future__ import annotations

import math

import numpy as np
import pybullet as p
import pytest

from craft_e.runtime.sim.assets import object_asset, object_catalog
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.placement import (
    Footprint,
    PlacementConfig,
    PlacementError,
    corners,
    rects_overlap,
    sample_layout,
)
from craft_e.runtime.sim.scene import SceneSpec

SPEC = SceneSpec(
    verb="cut",
    target="knife",
    distractors=("flat_screwdriver", "mustard_bottle", "a_cups", "glue_1"),
    seed=3,
)


def test_catalog_maps_sim_assets_to_plain_names_and_files_exist() -> None:
    expected = {
        "mustard_bottle": "mustard bottle",
        "a_cups": "cup",
        "glue_1": "glue",
        "mini_claw_hammer_1": "hammer",
        "stapler_2": "stapler",
        "remote_controller_1": "remote",
        "knife": "knife",
    }
    for asset_id, name in expected.items():
        assert object_asset(asset_id).name == name
    catalog = object_catalog()
    assert len(catalog) >= 70
    for asset in catalog.values():
        assert asset.urdf_path.is_file(), asset  # raises with the shared folder named if missing
    with pytest.raises(KeyError, match="known:"):
        object_asset("no_such_object")


def test_sampled_footprints_do_not_overlap_and_stay_in_the_workspace() -> None:
    footprints = [Footprint((0.01, 0.0), (0.11, 0.015))] * 3 + [
        Footprint((0.0, 0.0), (0.04, 0.04))
    ] * 2
    config = PlacementConfig()
    poses = sample_layout(footprints, np.random.default_rng(7), config)
    quads = [corners(f, pose, config.margin / 2) for f, pose in zip(footprints, poses, strict=True)]
    for i in range(len(quads)):
        assert config.centers.x_min <= poses[i].x <= config.centers.x_max
        assert config.centers.y_min <= poses[i].y <= config.centers.y_max
        assert config.bounds.contains(quads[i])
        for j in range(i + 1, len(quads)):
            assert not rects_overlap(quads[i], quads[j])
    again = sample_layout(footprints, np.random.default_rng(7), config)
    assert again == poses


def test_placement_gives_up_with_a_clear_error() -> None:
    huge = [Footprint((0.0, 0.0), (0.2, 0.2))] * 3
    with pytest.raises(PlacementError, match="could not place"):
        sample_layout(huge, np.random.default_rng(0), PlacementConfig(restarts=2))


def _settled_poses(spec: SceneSpec) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    with SimEnv() as env:
        scene = env.reset(spec)
        return {o.asset_id: scene.pose(o.body_id) for o in scene.objects}


def test_scene_is_deterministic_per_seed_and_objects_rest_on_the_table() -> None:
    first = _settled_poses(SPEC)
    second = _settled_poses(SPEC)
    assert first.keys() == second.keys() == set(SPEC.assets)
    for asset, (pos, quat) in first.items():
        assert np.array_equal(pos, second[asset][0]), asset  # bit for bit, not approximately
        assert np.array_equal(quat, second[asset][1]), asset
    other = _settled_poses(SceneSpec(SPEC.verb, SPEC.target, SPEC.distractors, SPEC.seed + 1))
    moved = [np.linalg.norm(first[a][0][:2] - other[a][0][:2]) for a in first]
    assert max(moved) > 0.02, "a different seed should give a different layout"

    with SimEnv() as env:
        scene = env.reset(SPEC)
        assert scene.target.asset_id == "knife" and scene.target.is_target
        for obj in scene.objects:
            touching = p.getContactPoints(obj.body_id, scene.table_id, physicsClientId=scene.client)
            assert touching, f"{obj.asset_id} is not resting on the table"
            assert min(c[8] for c in touching) > -0.005, f"{obj.asset_id} sinks into the table"
            lo, hi = p.getAABB(obj.body_id, physicsClientId=scene.client)
            cx, cy = (lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2
            assert 0.14 <= cx <= 0.61 and -0.30 <= cy <= 0.30, obj.asset_id
            velocity = np.linalg.norm(
                p.getBaseVelocity(obj.body_id, physicsClientId=scene.client)[0]
            )
            assert velocity < 0.01, f"{obj.asset_id} still moving after settling"


def test_camera_model_matches_the_renderer() -> None:
    """A world point projects, through the recorded intrinsics and pose, onto its own pixels."""
    with SimEnv() as env:
        env.reset(SceneSpec("x", "foam_brick", (), seed=0))
        client = env.client
        centres = [(0.30, -0.15, 0.05), (0.45, 0.12, 0.02), (0.38, 0.0, 0.10)]
        bodies = []
        for centre in centres:
            shape = p.createVisualShape(p.GEOM_SPHERE, radius=0.008, physicsClientId=client)
            bodies.append(p.createMultiBody(0, -1, shape, list(centre), physicsClientId=client))
        obs = env.capture()
        world_to_cam = np.linalg.inv(obs.cam_to_world)
        for centre, body in zip(centres, bodies, strict=True):
            pc = world_to_cam @ np.array([*centre, 1.0])
            u, v = obs.intrinsics.project(pc[:3])
            assert obs.seg is not None
            rows, cols = np.nonzero(obs.seg == body)
            assert rows.size > 50, f"sphere at {centre} not rendered"
            assert math.hypot(cols.mean() - u, rows.mean() - v) < 0.4
            # and depth at the sphere's centre pixel is its distance minus the radius
            z = obs.depth[round(float(v)), round(float(u))]
            assert z == pytest.approx(pc[2] - 0.008, abs=0.001)
        table = obs.points_world()[obs.seg == env.scene.table_id]
        assert np.abs(table[:, 2]).max() < 1e-4  # table top is z = 0 in the world frame
