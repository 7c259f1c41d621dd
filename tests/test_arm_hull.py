"""The arm links' hull samples (``sim.arm_hull``): on the hull, dense enough, and where pybullet
puts the links.

Why: the clearance check reads these points as the arm; points off the links, too sparse, or
in the wrong frame would let a forearm come down on a tall neighbour unseen (the misses that
motivated them) or block approaches that are clear.
"""

from __future__ import annotations

import itertools

import numpy as np
import pybullet as p
import pytest

from craft_e.runtime.sim.arm_hull import hull_points_world, hull_surface_points, link_hulls
from craft_e.runtime.sim.clearance import ClearanceConfig
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.robot_urdf import robot_urdf_path
from craft_e.runtime.sim.scene import SceneSpec

CUBE = np.array(list(itertools.product((0.0, 0.1), repeat=3)), dtype=np.float64)


def test_cube_samples_lie_on_its_faces_and_cover_them() -> None:
    spacing = 0.01
    pts = hull_surface_points(CUBE, spacing)
    on_face = np.isclose(pts, 0.0, atol=1e-9) | np.isclose(pts, 0.1, atol=1e-9)
    assert on_face.any(axis=1).all()  # every sample is on a face
    assert ((pts >= -1e-9) & (pts <= 0.1 + 1e-9)).all()
    # every point of the surface has a sample within a cell's diagonal
    rng = np.random.default_rng(0)
    probe = rng.uniform(0.0, 0.1, (500, 3))
    axis = rng.integers(0, 3, 500)
    probe[np.arange(500), axis] = rng.choice([0.0, 0.1], 500)
    nearest = np.min(np.linalg.norm(probe[:, None, :] - pts[None, :, :], axis=2), axis=1)
    assert nearest.max() <= spacing * np.sqrt(3)
    # one sample per spacing cube: no more than the cubes the surface passes through
    cells = {tuple(c) for c in np.floor(pts / spacing).astype(int)}
    assert len(cells) == len(pts)


def test_each_cell_keeps_its_lowest_sample() -> None:
    """The check asks whether anything rises above a link: per cell, the lowest point counts."""
    pts = hull_surface_points(CUBE, 0.05)
    bottom = pts[np.isclose(pts[:, 2], 0.0)]
    assert len(bottom) > 0
    for c in np.floor(bottom / 0.05).astype(int):
        same = (np.floor(pts / 0.05).astype(int) == c).all(axis=1)
        assert same.sum() == 1


def test_spacing_must_be_positive() -> None:
    with pytest.raises(ValueError, match="spacing"):
        hull_surface_points(CUBE, 0.0)


@pytest.mark.parametrize("seed", [0, 1])
def test_link_hulls_sit_on_the_links_pybullet_collides(seed: int) -> None:
    """For random arm postures, a 1 mm probe sphere at any link's hull sample touches that link
    in pybullet (closest distance within 3 mm), and one 3 cm further out from the link's centre
    does not touch it: the samples are on the simulated links' surfaces, in the right frames."""
    cfg = ClearanceConfig()
    with SimEnv() as env:
        env.reset(SceneSpec("cut", "knife", ("apple",), 0))
        robot, client = env.robot, env.client
        hulls = link_hulls(robot.urdf_path, cfg.arm_links, cfg.arm_spacing)
        names = [p.getJointInfo(robot.body_id, j, physicsClientId=client)[12].decode()
                 for j in range(p.getNumJoints(robot.body_id, physicsClientId=client))]
        probe_shape = p.createCollisionShape(p.GEOM_SPHERE, radius=0.001, physicsClientId=client)
        probe = p.createMultiBody(0.0, probe_shape, basePosition=[5.0, 5.0, 5.0], physicsClientId=client)
        rng = np.random.default_rng(seed)

        def distance(link: int, where: np.ndarray) -> float:
            p.resetBasePositionAndOrientation(probe, where.tolist(), [0, 0, 0, 1], physicsClientId=client)
            near = p.getClosestPoints(robot.body_id, probe, 0.1, linkIndexA=link, physicsClientId=client)
            return min((c[8] for c in near), default=1.0)

        for _ in range(2):
            q = rng.uniform(-2.5, 2.5, 6)
            for joint, value in zip(robot.arm_joints, q, strict=True):
                p.resetJointState(robot.body_id, joint, float(value), physicsClientId=client)
            _, frames = robot.forward_and_frames(q)
            for hull, world in zip(hulls, hull_points_world(hulls, frames, robot.base_position), strict=True):
                link = names.index(hull.link)
                centre = world.mean(axis=0)
                for point in world[rng.choice(len(world), 15, replace=False)]:
                    assert abs(distance(link, point)) <= 0.003, (hull.link, point)
                    out = point + 0.03 * (point - centre) / np.linalg.norm(point - centre)
                    assert distance(link, out) > 0.0, (hull.link, out)


def test_unknown_link_is_named() -> None:
    with pytest.raises(ValueError, match="Link9"):
        link_hulls(robot_urdf_path(), ("Link9",), 0.01)
