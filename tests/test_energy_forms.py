"""Every E_aff form on a hand-made 2-verb x 3-property x 4-object KB, values worked out by hand.

    w_vp            p0    p1    p2          w_po   o0    o1    o2    o3     df (w_po >= 0.5)
    v0             1.0   0.5   0.0          p0    0.9   0.0   0.0   0.0     1
    v1             0.0   0.4   0.8          p1    0.8   0.6   0.7   0.9     4 (every object)
                                            p2    0.0   0.3   1.0   0.0     1 (0.3 < tau)

Specificity s_p = log(4 / df_p) / log(4): p0 = 1, p1 = 0, p2 = 1.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from runtime_fixtures import RuntimeKBs, runtime_kbs_fixture  # noqa: F401

from craft_e.runtime.grounding.energies import (
    ENERGY_FORMS,
    affordance_energy_matrix,
    check_energy_form,
    property_specificity,
    required_matrix_from_graph,
)
from craft_e.runtime.grounding.grounder import Grounder, affordance_energy_in_form
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.schemas.v1.bundle import EnergyInfo
from craft_e.schemas.v1.graph import GraphEdge, KnowledgeGraph

W_VP = np.array([[1.0, 0.5, 0.0], [0.0, 0.4, 0.8]], dtype=np.float32)
W_PO = np.array(
    [[0.9, 0.0, 0.0, 0.0], [0.8, 0.6, 0.7, 0.9], [0.0, 0.3, 1.0, 0.0]], dtype=np.float32
)
#: v0 requires p0 (only o0 has it); v1 requires nothing.
REQUIRED = np.array([[True, False, False], [False, False, False]])

# v0: sum w_vp = 1.5; o0 1*0.9 + 0.5*0.8 = 1.3; o1 0.5*0.6; o2 0.5*0.7; o3 0.5*0.9
# v1: sum w_vp = 1.2; o0 0.4*0.8; o1 0.4*0.6 (p2 0.3 < tau); o2 0.4*0.7 + 0.8*1.0; o3 0.4*0.9
NORMALIZED = [[-1.3 / 1.5, -0.3 / 1.5, -0.35 / 1.5, -0.45 / 1.5],
              [-0.32 / 1.2, -0.24 / 1.2, -1.08 / 1.2, -0.36 / 1.2]]  # fmt: skip
# specificity: v0 keeps only p0 (weight 1): o0 -0.9; v1 keeps only p2 (0.8): o2 -0.8 / 0.8
SPECIFICITY = [[-0.9, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]]
# veto: v0's required p0 is missing on o1..o3 -> 0; v1 has no required property -> unchanged
REQUIRED_VETO = [[-1.3 / 1.5, 0.0, 0.0, 0.0], NORMALIZED[1]]
SPECIFICITY_VETO = [[-0.9, 0.0, 0.0, 0.0], SPECIFICITY[1]]
SUM_TANH = [[math.tanh(-(1.9 + 1.3)), math.tanh(-1.1), math.tanh(-1.2), math.tanh(-1.4)],
            [math.tanh(-1.2), math.tanh(-1.0), math.tanh(-(1.1 + 1.8)), math.tanh(-1.3)]]  # fmt: skip

EXPECTED = {
    "sum-tanh": SUM_TANH,
    "normalized-product": NORMALIZED,
    "specificity": SPECIFICITY,
    "required-veto": REQUIRED_VETO,
    "specificity-veto": SPECIFICITY_VETO,
}


def test_every_form_is_covered() -> None:
    assert set(EXPECTED) == set(ENERGY_FORMS)
    assert ENERGY_FORMS[0] == "sum-tanh"
    # the manifest schema accepts exactly the runtime's forms
    assert set(EnergyInfo.model_fields["form"].annotation.__args__) == set(ENERGY_FORMS)  # type: ignore[union-attr]


@pytest.mark.parametrize("form", list(EXPECTED))
def test_hand_values(form: str) -> None:
    got = affordance_energy_matrix(W_VP, W_PO, tau=0.5, form=check_energy_form(form), required=REQUIRED)
    assert got.dtype == np.float32 and got.shape == (2, 4)
    np.testing.assert_allclose(got, EXPECTED[form], atol=1e-6)


def test_specificity_factor() -> None:
    np.testing.assert_allclose(property_specificity(W_PO, tau=0.5), [1.0, 0.0, 1.0], atol=1e-12)
    # a property no object has counts as fully specific; 2 of 4 objects -> log 2 / log 4 = 0.5
    w_po = np.array([[0.0, 0.0, 0.0, 0.0], [0.6, 0.6, 0.0, 0.0]], dtype=np.float32)
    np.testing.assert_allclose(property_specificity(w_po, tau=0.5), [1.0, 0.5], atol=1e-12)
    assert property_specificity(np.ones((3, 1), np.float32)).tolist() == [1.0, 1.0, 1.0]


def test_veto_forms_without_roles_equal_their_base_forms() -> None:
    """v1 bundles have no roles: no required matrix, or an all-False one, vetoes nothing."""
    for required in (None, np.zeros_like(REQUIRED)):
        np.testing.assert_allclose(
            affordance_energy_matrix(W_VP, W_PO, form="required-veto", required=required), NORMALIZED, atol=1e-6
        )
        np.testing.assert_allclose(
            affordance_energy_matrix(W_VP, W_PO, form="specificity-veto", required=required), SPECIFICITY, atol=1e-6
        )


def test_required_flag_on_a_missing_edge_is_ignored_and_shape_checked() -> None:
    stray = REQUIRED.copy()
    stray[0, 2] = True  # v0 has no edge to p2: its flag must not veto anything
    np.testing.assert_allclose(
        affordance_energy_matrix(W_VP, W_PO, form="required-veto", required=stray), REQUIRED_VETO, atol=1e-6
    )
    with pytest.raises(ValueError, match="required must be"):
        affordance_energy_matrix(W_VP, W_PO, form="required-veto", required=REQUIRED[:, :2])


def test_unknown_form_is_an_error_listing_the_forms() -> None:
    with pytest.raises(ValueError, match="specificity-veto"):
        affordance_energy_matrix(W_VP, W_PO, form="product")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="required-veto"):
        check_energy_form("veto")


def test_required_matrix_from_graph() -> None:
    graph = KnowledgeGraph(nodes=[], edges=[
        GraphEdge(source="verb:cut", target="prop:sharp edge", weight=0.9, provenance=[], role="required"),
        GraphEdge(source="verb:cut", target="prop:has a handle", weight=0.4, provenance=[], role="helpful"),
        GraphEdge(source="verb:pour", target="prop:has a spout", weight=0.8, provenance=[]),  # v1: no role
        GraphEdge(source="prop:sharp edge", target="obj:knife", weight=0.95, provenance=[]),
    ])  # fmt: skip
    req = required_matrix_from_graph(graph, ["cut", "pour"], ["has a handle", "has a spout", "sharp edge"])
    assert req.tolist() == [[False, False, True], [False, False, False]]


@pytest.mark.parametrize("form", ENERGY_FORMS)
def test_grounder_accepts_every_form(runtime_kbs: RuntimeKBs, form: str) -> None:
    kb = load_bundle(runtime_kbs.kb)
    grounder = Grounder(kb, GroundingSettings(energy_form=form))
    assert grounder.energy_form == form
    matrix = affordance_energy_in_form(kb, form)  # type: ignore[arg-type]
    assert matrix.shape == kb.energy.shape and (matrix <= 1.0).all() and (matrix >= -1.0).all()
    # the "never pick" override holds in every form
    assert matrix[kb.verb_index["cut"], kb.object_index["umbrella"]] == 1.0
    with pytest.raises(ValueError, match="energy_form"):
        Grounder(kb, GroundingSettings(energy_form="veto"))
