"""The camera effects of ``benchmarks/bench_frame_noise.py``.

Why: the benchmark's numbers are only comparable between runs if every draw is seeded, and only
mean "a real camera's frame" if the effects leave missing readings missing (a camera with no
reading at a pixel gives 0, not noise) and quantise as a uint16 RealSense frame does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import load_script

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_frame_noise.py"


def test_the_noise_and_holes_are_seeded_touch_only_readings_and_depth_is_whole_millimetres() -> None:
    bench = load_script(SCRIPT)
    rng = np.random.default_rng(7)
    depth = rng.uniform(0.5, 0.9, size=(60, 80)).astype(np.float32)
    depth[:10] = 0.0  # no reading: the top rows
    missing = depth == 0

    noisy = bench.gaussian_noise(depth, 0.002, np.random.default_rng([0, 1, 2]))
    assert noisy.dtype == np.float32
    np.testing.assert_array_equal(noisy, bench.gaussian_noise(depth, 0.002, np.random.default_rng([0, 1, 2])))
    assert not np.array_equal(noisy, bench.gaussian_noise(depth, 0.002, np.random.default_rng([1, 1, 2])))
    assert np.all(noisy[missing] == 0) and np.all(noisy[~missing] > 0)
    assert np.std(noisy[~missing] - depth[~missing]) == pytest.approx(0.002, rel=0.1)

    holed = bench.drop_blocks(depth, 0.02, np.random.default_rng(3))
    np.testing.assert_array_equal(holed, bench.drop_blocks(depth, 0.02, np.random.default_rng(3)))
    new_holes = (holed == 0) & ~missing
    assert np.all(holed[missing] == 0)
    assert round(0.02 * depth.size) <= new_holes.sum() < round(0.02 * depth.size) + 9
    np.testing.assert_array_equal(holed[~new_holes], depth[~new_holes])  # the rest untouched

    mm = bench.quantise_mm(depth)
    assert mm.dtype == np.float32
    np.testing.assert_allclose(mm * 1000, np.rint(depth * 1000), atol=1e-3)
    assert np.all(mm[missing] == 0)
    assert np.max(np.abs(mm - depth)) <= 0.0005 + 1e-6
