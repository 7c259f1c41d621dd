"""``aff_norm`` "verb-best": each verb's E_aff scaled so its best object in the bundle sits at -1."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from runtime_fixtures import RuntimeKBs, runtime_kbs_fixture  # noqa: F401

from craft_e.runtime.evaluation.methods import MethodSpec, method_settings
from craft_e.runtime.grounding.energies import FORBIDDEN_ENERGY, scale_negative, verb_best_divisor
from craft_e.runtime.grounding.grounder import ROI, Grounder
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import load_bundle


def test_divisor_puts_each_rows_best_at_minus_one_and_leaves_the_rest() -> None:
    energy = np.array([[-0.5, -0.25, 0.0, FORBIDDEN_ENERGY],  # best -0.5 -> divisor 0.5
                       [0.0, 0.0, 0.0, 0.0],  # nothing affordant: divisor 1, row unchanged
                       [-1.0, -0.2, 0.0, 0.0]], dtype=np.float32)  # already at -1
    divisor = verb_best_divisor(energy)
    assert divisor.shape == (3, 1)
    assert divisor[:, 0].tolist() == pytest.approx([0.5, 1.0, 1.0])
    scaled = scale_negative(energy, divisor)
    assert scaled.tolist()[0] == pytest.approx([-1.0, -0.5, 0.0, FORBIDDEN_ENERGY])  # forbidden kept at its value
    assert scaled.tolist()[1] == [0.0, 0.0, 0.0, 0.0]
    assert scaled.tolist()[2] == pytest.approx([-1.0, -0.2, 0.0, 0.0])


def _roi(kb: Any, name: str) -> ROI:
    return ROI((0, 0, 10, 10), [0.8], image_embedding=kb.embeddings["object"][kb.object_index[name]])


def test_grounder_scales_each_verb_by_its_best_bundle_object(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    plain, scaled = Grounder(kb, GroundingSettings(aff_norm="none")), Grounder(kb, GroundingSettings(aff_norm="verb-best"))
    for verb in kb.manifest.verbs:
        row0, row1 = plain._plan(verb).row, scaled._plan(verb).row
        if row0.min() < 0:
            assert row1.min() == pytest.approx(-1.0)
            # the same order of objects within the verb: only its scale against E_grasp/E_align moves
            assert np.array_equal(np.argsort(row0, kind="stable"), np.argsort(row1, kind="stable"))
            assert row1 == pytest.approx(row0 / -row0.min(), abs=1e-6)
    # an ROI's E_aff (the expectation over hypotheses) scales by the same divisor; E_grasp/E_align do not
    rois = [_roi(kb, "hatchet"), _roi(kb, "banana")]
    r0 = {r.index: r for r in plain.ground("cut", rois).ranked}
    r1 = {r.index: r for r in scaled.ground("cut", rois).ranked}
    best = -float(plain._plan("cut").row.min())
    for i in r0:
        assert r1[i].e_aff == pytest.approx(r0[i].e_aff / best, abs=1e-6)
        assert (r1[i].e_grasp, r1[i].e_align) == pytest.approx((r0[i].e_grasp, r0[i].e_align))
    # the terminal report says which scale its E_aff column is on
    assert "scaled per verb" in scaled.ground("cut", rois).render()
    assert "scaled per verb" not in plain.ground("cut", rois).render()
    assert scaled.settings.energy_dict()["aff_norm"] == "verb-best"
    assert "aff_norm" not in plain.settings.energy_dict()  # off: results stored before the option read the same


def test_the_scale_is_the_bundles_not_the_scene_vocabularys(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    row = Grounder(kb, GroundingSettings(aff_norm="none"))._plan("cut").row
    weaker = [j for j in np.argsort(row, kind="stable").tolist() if row[j] > 0.95 * row.min()]  # clearly below the best
    rest = [kb.manifest.objects[j] for j in weaker[:3]]
    scene = Grounder(kb, GroundingSettings(aff_norm="verb-best", vocabulary=tuple(rest)))
    # without the KB's best object in the scene, the scene's best stays above -1: the divisor is the
    # KB's, so the same object scores the same in every scene
    expected = [float(row[kb.object_index[o]]) / -float(row.min()) for o in rest]
    assert scene._plan("cut").row.tolist() == pytest.approx(expected, abs=1e-6)
    assert min(expected) > -0.96 and min(expected) < 0


def test_settings_and_method_specs_carry_the_option() -> None:
    assert GroundingSettings.of(aff_norm=None).aff_norm == GroundingSettings().aff_norm  # unset: the default
    with pytest.raises(ValueError, match="--aff-norm 'max': use one of none, verb-best"):
        GroundingSettings.of(aff_norm="max")
    base = GroundingSettings(aff_norm="none")
    spec = MethodSpec("x", "", Path("kb"), aff_norm="verb-best")
    assert method_settings(spec, base, ["cup"]).aff_norm == "verb-best"
    assert method_settings(MethodSpec("y", "", Path("kb")), base, ["cup"]).aff_norm == "none"  # the run's


def test_a_free_request_is_scaled_by_its_own_best_bundle_object(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    options = {"open_vocab": True}
    plain = Grounder(kb, GroundingSettings(aff_norm="none", **options), request_min_confidence=0.0)
    scaled = Grounder(kb, GroundingSettings(aff_norm="verb-best", **options), request_min_confidence=0.0)
    row0, row1 = plain._plan("chop firewood").row, scaled._plan("chop firewood").row  # over the KB's objects
    assert row0.min() < 0 and row1.min() == pytest.approx(-1.0)
    assert row1 == pytest.approx(np.where(row0 < 0, row0 / -row0.min(), row0), abs=1e-6)
