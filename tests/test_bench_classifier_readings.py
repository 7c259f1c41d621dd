"""The classifier-readings benchmark's own logic: each reading is a distribution over the 1000
classes, the default reading is the pipeline's probabilities untouched, and the encoder it records
through changes nothing."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import load_script

bench = load_script(Path(__file__).resolve().parents[1] / "benchmarks" / "bench_classifier_readings.py")


def _probs(rng: np.random.Generator, n: int = 4) -> np.ndarray:
    p = rng.random((n, 1000)) ** 4
    return p / p.sum(axis=1, keepdims=True)


def test_every_reading_is_a_distribution_and_the_default_is_untouched() -> None:
    rng = np.random.default_rng(0)
    p = {key: _probs(rng) for key in ("lite1", "lite1_mirror", "lite0", "lite0_mirror")}
    priors = {0: rng.random(1000) + 0.01}
    found = bench.readings(priors)
    assert len(found) == 7
    for name, read in found.items():
        out = read(p, 0)
        assert out.shape == (4, 1000), name
        np.testing.assert_allclose(out.sum(axis=1), 1.0, atol=1e-9, err_msg=name)
        assert (out >= 0).all(), name
    assert next(iter(found.values()))(p, 0) is p["lite1"]


def test_the_ensembles_of_one_classifier_with_itself_are_that_classifier() -> None:
    rng = np.random.default_rng(1)
    same = _probs(rng)
    p = {"lite1": same, "lite0": same, "lite1_mirror": same, "lite0_mirror": same}
    found = bench.readings({0: np.full(1000, 1e-3)})
    for name in ("Lite1 + Lite0, mean", "Lite1 + Lite0, geometric mean", "Lite1 + Lite0, each + mirror, mean"):
        np.testing.assert_allclose(found[name](p, 0), same, rtol=1e-6, atol=1e-12, err_msg=name)


def test_the_prior_correction_lowers_the_classes_the_scenes_favour() -> None:
    p = {"lite1": np.full((1, 1000), 1e-3)}
    prior = np.full(1000, 1e-3)
    prior[7] = 0.5  # one class the other seeds' crops pile onto
    read = next(f for name, f in bench.readings({3: prior}).items() if "prior" in name)
    out = read(p, 3)
    assert out[0, 7] < out[0, 8]
    np.testing.assert_allclose(out[0, 7] / out[0, 8], (1e-3 / 0.5) ** bench.PRIOR_EXPONENT)


def test_the_recording_encoder_passes_probabilities_through_and_keeps_them() -> None:
    class Inner:
        dim = 384
        id = "inner"

        def class_probabilities(self, crops: list[np.ndarray], batch_size: int = 16) -> np.ndarray:
            return np.full((len(crops), 1000), 1e-3, dtype=np.float32)

    recorder = bench.RecordingEncoder(Inner())
    crops = [np.zeros((8, 8, 3), np.uint8)] * 2
    out = recorder.class_probabilities(crops)
    assert out.dtype == np.float32 and out.shape == (2, 1000)
    assert recorder.probs is not None and recorder.probs.shape == (2, 1000) and len(recorder.crops) == 2
    assert recorder.dim == 384 and recorder.id == "inner"  # everything else is the inner encoder's


def test_one_seed_is_refused_before_any_work(monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(sys, "argv", ["bench_classifier_readings.py", "--seed", "0"])
    with pytest.raises(SystemExit) as stop:
        bench.main()
    assert stop.value.code == 2
    assert "two or more --seed values" in capsys.readouterr().err
