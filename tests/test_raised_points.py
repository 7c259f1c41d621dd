"""The robot's partial world transforms equal the whole frame's, bit for bit.

``Observation.points_camera`` fills one array from cached ray factors, ``world_z`` and
``points_world_at`` transform only what the robot reads, and ``RaisedPoints`` serves the grasp
checks, the size cue, the clearance maps and relocation from them (``runtime/sim/surface.py``).
Every consumer used to read the whole frame's arrays, and published results must reproduce, so
these are compared with ``==``, not a tolerance.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from craft_e.runtime.grasp.geometry import CameraIntrinsics
from craft_e.runtime.perception.observation import Observation
from craft_e.runtime.sim.perceive import raised_mask
from craft_e.runtime.sim.surface import RaisedPoints, object_centre


def _frame(seed: int) -> Observation:
    """A tilted camera over a table at z = 0.7 with boxes on it, some pixels without depth."""
    rng = np.random.default_rng(seed)
    h, w = 60, 80
    intrinsics = CameraIntrinsics(width=w, height=h, fx=71.3, fy=69.9, cx=39.2, cy=30.7)
    depth = (0.65 + 0.01 * rng.standard_normal((h, w))).astype(np.float32)
    depth[10:25, 20:40] -= 0.08  # something standing on the table
    depth[40:50, 5:15] -= 0.02
    depth[rng.random((h, w)) < 0.05] = 0.0  # no reading
    depth[0, :3] = np.nan
    angle = 0.3
    rotation = np.array([[1.0, 0.0, 0.0],
                         [0.0, -np.cos(angle), np.sin(angle)],
                         [0.0, -np.sin(angle), -np.cos(angle)]])
    cam_to_world = np.eye(4)
    cam_to_world[:3, :3], cam_to_world[:3, 3] = rotation, [0.4, 0.1, 1.35]
    return Observation(rgb=np.zeros((h, w, 3), np.uint8), depth=depth, intrinsics=intrinsics,
                       cam_to_world=cam_to_world)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_points_camera_equals_deproject(seed: int) -> None:
    obs = _frame(seed)
    h, w = obs.shape
    v, u = np.mgrid[0:h, 0:w]
    z = obs.depth.astype(np.float64)
    z = np.where(np.isfinite(z) & (z > 0), z, np.nan)
    expected = obs.intrinsics.deproject(np.stack([u, v], axis=-1).astype(np.float64), z)
    got = obs.points_camera()
    assert got.shape == (h, w, 3) and not got.flags.writeable
    assert np.array_equal(got, expected, equal_nan=True)
    assert np.isnan(got[0, 0]).all()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_partial_world_transforms_equal_the_whole_frame(seed: int) -> None:
    obs = _frame(seed)
    whole = dataclasses.replace(obs).points_world()  # a fresh frame: nothing cached yet
    assert np.array_equal(obs.world_z(), whole[..., 2], equal_nan=True)
    pixels = np.flatnonzero(np.random.default_rng(seed).random(obs.shape) < 0.3)
    assert np.array_equal(obs.points_world_at(pixels), whole.reshape(-1, 3)[pixels], equal_nan=True)
    # once the whole frame is transformed, the partial views read it
    obs.points_world()
    assert np.array_equal(obs.points_world_at(pixels), whole.reshape(-1, 3)[pixels], equal_nan=True)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_raised_points_match_the_whole_frame_masks(seed: int) -> None:
    obs = _frame(seed)
    table_z, tolerance = 0.02, 0.004
    world = dataclasses.replace(obs).points_world()
    mask = raised_mask(world, table_z, tolerance)
    raised = RaisedPoints.of(obs, table_z, tolerance)
    assert 0 < int(mask.sum()) < mask.size
    assert np.array_equal(raised.mask, mask)
    region = np.zeros(obs.shape, dtype=bool)
    region[5:30, 15:45] = True
    assert np.array_equal(raised.within(region), world[region & mask])
    assert np.array_equal(raised.outside(region), world[~region & mask])
    assert len(raised.within(region)) + len(raised.outside(region)) == int(mask.sum())


def test_a_negative_tolerance_is_refused() -> None:
    with pytest.raises(ValueError, match="tolerance must be >= 0"):
        RaisedPoints.of(_frame(0), 0.02, -0.001)


def test_object_centre_is_the_mean_of_the_regions_raised_points() -> None:
    obs = _frame(0)
    table_z, tolerance = 0.8, 0.004  # the 8 cm block stands above this (and a few noisy pixels)
    raised = RaisedPoints.of(obs, table_z, tolerance)
    region = np.zeros(obs.shape, dtype=bool)
    region[5:30, 15:45] = True  # around the block, with some table
    points = raised.within(region)
    assert len(points) > 100
    assert np.array_equal(points, raised.within(region & raised.mask))  # only raised points count
    centre = object_centre(raised, region)
    assert centre == (float(points[:, 0].mean()), float(points[:, 1].mean()))
    assert object_centre(raised, np.zeros(obs.shape, dtype=bool)) is None
