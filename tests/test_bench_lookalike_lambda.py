"""The look-alike λ grid weighs its cue on the p(o|r) the evaluations read: with the depth cues,
exactly what ``craft eval sim``'s CRAFT-E grounder reads at the day's defaults. Until 2026-12-07
the script read the size cue alone (no cavity cue), so its base matched no recognition row."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from conftest import load_script

from craft_e.paths import KB_DIR
from craft_e.runtime.encoders.conse import load_class_embeddings
from craft_e.runtime.evaluation.methods import build_grounders, load_methods, select_methods
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.runtime.sim.pipeline import sim_vocabulary

bench = load_script(Path(__file__).resolve().parents[1] / "benchmarks" / "bench_lookalike_lambda.py")


def _inputs() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Three crops ConSE would spread over a few classes, with a cup-like, a flat and an
    unmeasured region's depth measurements."""
    classes = load_class_embeddings()
    crops = np.stack([classes[:3].mean(axis=0), classes[400:410].mean(axis=0), classes[900:905].mean(axis=0)])
    extents = np.array([[0.09, 0.08, 0.10], [0.20, 0.05, 0.02], [np.nan] * 3])
    cavities = np.array([0.06, -0.004, np.nan])
    return crops.astype(np.float32), extents, cavities


def test_the_depth_reading_is_the_evaluations_crafte_grounders() -> None:
    crops, extents, cavities = _inputs()
    vocabulary = list(sim_vocabulary())
    bundle = load_bundle(KB_DIR / "craft-e-default", check_encoder=False)
    base = bench.base_readings(bundle, vocabulary, crops, extents, cavities)
    runnable, _ = load_methods(select_methods(["CRAFT-E"]))
    grounder = build_grounders(runnable, GroundingSettings(), vocabulary)["CRAFT-E"]
    assert grounder.cavity_cue_active and grounder.hubness_active and grounder.senses_active
    want = grounder.energies("cut", crops, extents=extents, cavities=cavities).p_obj
    np.testing.assert_allclose(base[True], want, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(base[False], grounder.image_hypotheses(crops), rtol=1e-6, atol=1e-9)
    # the depth cues move p(o|r): the two columns are different readings
    assert not np.allclose(base[True], base[False])
