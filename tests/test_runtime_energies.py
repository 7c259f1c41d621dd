"""E_aff in both forms against hand computation from the answer files; E_grasp; p(o|r)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from runtime_fixtures import TAU, RuntimeKBs, runtime_kbs_fixture  # noqa: F401

from craft_e.runtime.grounding.energies import (
    affordance_energy_matrix,
    grasp_energy,
    object_hypotheses,
    weight_matrices_from_graph,
)
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.kb.bundle import load_bundle

FORBIDDEN = ("cut", "umbrella")


def hand_sum_tanh(kbs: RuntimeKBs, verb: str, obj: str) -> float:
    """tanh(-sum over properties p of v with w_po(p, o) >= tau of (w_vp + w_po)), by loops."""
    total = 0.0
    for prop, w_vp in kbs.w_vp[verb].items():
        w_po = kbs.w_po.get(prop, {}).get(obj, 0.0)
        if w_po >= TAU:
            total += w_vp + w_po
    return math.tanh(-total)


def hand_normalized_product(kbs: RuntimeKBs, verb: str, obj: str) -> float:
    """-sum_p w_vp * w_po / sum_p w_vp over v's properties (w_po counted only if >= tau)."""
    num = sum(w_vp * kbs.w_po.get(p, {}).get(obj, 0.0) for p, w_vp in kbs.w_vp[verb].items()
              if kbs.w_po.get(p, {}).get(obj, 0.0) >= TAU)
    return -num / sum(kbs.w_vp[verb].values())


def test_literal_hand_values(runtime_kbs: RuntimeKBs) -> None:
    """Two pairs worked out on paper: broom for "hit" and umbrella for "pour"."""
    kb = load_bundle(runtime_kbs.kb)
    e = kb.energy
    # hit -> broom: has a handle (0.6 + 0.95), hand-held (0.5 + 0.9), swingable (0.7 + 0.5)
    assert e[kb.verb_index["hit"], kb.object_index["broom"]] == pytest.approx(math.tanh(-4.15), abs=1e-6)
    # pour -> umbrella: has a handle (0.5 + 0.95), hand-held (0.5 + 0.9), lightweight (0.3 + 0.8)
    assert e[kb.verb_index["pour"], kb.object_index["umbrella"]] == pytest.approx(math.tanh(-3.95), abs=1e-6)
    norm = Grounder._affordance_matrix(kb, "normalized-product")
    # hit: sum w_vp = 6.3; 0.6*0.95 + 0.5*0.9 + 0.7*0.5 = 1.37
    assert norm[kb.verb_index["hit"], kb.object_index["broom"]] == pytest.approx(-1.37 / 6.3, abs=1e-6)
    # eat -> umbrella: no property of "eat" links to an umbrella
    assert e[kb.verb_index["eat"], kb.object_index["umbrella"]] == 0.0


@pytest.mark.parametrize("form", ["sum-tanh", "normalized-product"])
def test_every_pair_matches_hand_computation(runtime_kbs: RuntimeKBs, form: str) -> None:
    kb = load_bundle(runtime_kbs.kb)
    matrix = kb.energy if form == "sum-tanh" else Grounder._affordance_matrix(kb, form)  # type: ignore[arg-type]
    hand = hand_sum_tanh if form == "sum-tanh" else hand_normalized_product
    for v in runtime_kbs.verbs:
        for o in runtime_kbs.objects:
            want = 1.0 if (v, o) == FORBIDDEN else hand(runtime_kbs, v, o)
            assert matrix[kb.verb_index[v], kb.object_index[o]] == pytest.approx(want, abs=1e-6), (v, o)


def test_runtime_recompute_matches_compiler_build(runtime_kbs: RuntimeKBs) -> None:
    """The normalized-product matrix the runtime rebuilds from graph.json equals the .npy the
    compiler writes when asked for that form (forbidden pairs included)."""
    kb, kb_norm = load_bundle(runtime_kbs.kb), load_bundle(runtime_kbs.kb_normalized)
    assert kb_norm.manifest.energy.form == "normalized-product"
    np.testing.assert_allclose(Grounder._affordance_matrix(kb, "normalized-product"), kb_norm.energy, atol=1e-6)
    np.testing.assert_allclose(Grounder._affordance_matrix(kb_norm, "sum-tanh"), kb.energy, atol=1e-6)


def test_weights_from_graph_and_forbidden(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    m = kb.manifest
    w_vp, w_po = weight_matrices_from_graph(kb.graph, m.verbs, m.properties, m.objects)
    assert w_vp.shape == (len(m.verbs), len(m.properties)) and w_po.shape == (len(m.properties), len(m.objects))
    p = m.properties.index("sharp edge")
    assert w_vp[m.verbs.index("cut"), p] == pytest.approx(0.95)
    assert w_po[p, m.objects.index("cleaver")] == pytest.approx(1.0)
    assert kb.graph.forbidden_pairs() == [FORBIDDEN]
    raw = affordance_energy_matrix(w_vp, w_po, tau=m.energy.tau)
    assert raw[m.verbs.index("cut"), m.objects.index("umbrella")] < 0  # 1.0 only after the override


def test_grasp_energy_clips() -> None:
    assert grasp_energy([0.2, 0.5]) == pytest.approx(-math.log(0.5))
    assert grasp_energy([0.0]) == pytest.approx(-math.log(1e-6))
    assert grasp_energy([1.7]) == 0.0
    assert grasp_energy([]) == math.inf


def test_object_hypotheses_is_a_stable_softmax() -> None:
    cos = np.array([[0.9, 0.1, 0.1], [0.0, 0.0, 0.0]], dtype=np.float32)
    p = object_hypotheses(cos, 0.01)
    np.testing.assert_allclose(p.sum(axis=1), 1.0, rtol=1e-6)
    assert p[0, 0] > 0.999 and np.allclose(p[1], 1 / 3)
    assert np.isfinite(object_hypotheses(cos * 1000, 1e-4)).all()
    with pytest.raises(ValueError, match="temperature"):
        object_hypotheses(cos, 0.0)
