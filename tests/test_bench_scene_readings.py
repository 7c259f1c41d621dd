"""The scene-readings benchmark's own logic: each reading keeps every region's row a distribution,
the default reading is the grounder's ``p(o | r)`` untouched, a lone region is read as before by
the readings that only share mass out, and the cap brings a shared name's total down."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from conftest import load_script

bench = load_script(Path(__file__).resolve().parents[1] / "benchmarks" / "bench_scene_readings.py")


def _scene(rng: np.random.Generator, regions: int = 5, names: int = 62) -> np.ndarray:
    p = rng.random((regions, names)) ** 6
    return p / p.sum(axis=1, keepdims=True)


def test_every_reading_keeps_distributions_and_the_default_is_untouched() -> None:
    p = _scene(np.random.default_rng(0))
    for name, read in bench.READINGS.items():
        out = read(p)
        assert out.shape == p.shape, name
        np.testing.assert_allclose(out.sum(axis=1), 1.0, atol=1e-9, err_msg=name)
        assert (out >= 0).all(), name
    assert next(iter(bench.READINGS.values()))(p) is p


def test_a_lone_region_is_read_as_before_by_the_cap_and_explaining_away() -> None:
    p = _scene(np.random.default_rng(1), regions=1)
    np.testing.assert_allclose(bench.column_cap(p, 1.0), p, atol=1e-12)
    np.testing.assert_allclose(bench.explained_away(p, 1.0), p, atol=1e-12)


def test_the_cap_brings_a_name_two_regions_claim_down_to_the_cap() -> None:
    p = np.array([[0.9, 0.1, 0.0], [0.8, 0.0, 0.2]])
    out = bench.column_cap(p, 1.0)
    assert out[:, 0].sum() <= 1.0 + 1e-4 < p[:, 0].sum()  # 20 rounds: within 1e-5 here
    assert out[0, 0] > out[1, 0]  # the region surer of the name keeps more of it
    explained = bench.explained_away(p, 1.0)
    assert explained[1, 0] < p[1, 0] and explained[1, 2] > p[1, 2]
