"""The robot's path runs numpy's BLAS on one thread (``runtime/blas.py``) and leaves torch's pool
alone; for the shapes the robot computes (inner dimension 3, an SVD of n x 3 points) one thread
gives the same bits as two, so published results do not move."""

from __future__ import annotations

import numpy as np
import torch
from threadpoolctl import threadpool_info, threadpool_limits

from craft_e.runtime.blas import single_threaded_blas
from craft_e.runtime.perception.plane import fit_plane


def _robot_shaped_work(seed: int) -> list[bytes]:
    rng = np.random.default_rng(seed)
    cloud = np.column_stack([rng.uniform(-0.3, 0.3, (40000, 2)), rng.normal(0.6, 0.001, 40000)])
    cloud[::7, 2] += 0.1  # clutter
    plane, inliers = fit_plane(cloud)
    rotation = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    world = cloud @ rotation.T + np.array([0.4, 0.1, 0.7])
    return [plane.normal.tobytes(), np.float64(plane.offset).tobytes(), np.int64(inliers).tobytes(),
            world.tobytes(), (cloud @ rotation[2]).tobytes()]


def test_blas_libraries_run_one_thread_and_torch_keeps_its_threads() -> None:
    before = torch.get_num_threads()
    single_threaded_blas()
    single_threaded_blas()  # idempotent
    blas = [lib for lib in threadpool_info() if lib["user_api"] == "blas"]
    assert blas, "numpy's BLAS was not found"
    assert all(lib["num_threads"] == 1 for lib in blas), blas
    assert torch.get_num_threads() == before


def test_robot_shaped_linear_algebra_is_the_same_on_one_thread_as_on_two() -> None:
    single_threaded_blas()
    one = _robot_shaped_work(0)
    with threadpool_limits(limits=2, user_api="blas"):
        two = _robot_shaped_work(0)
    assert one == two
