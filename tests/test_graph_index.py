"""Grounding reads a bundle's graph through ``GraphIndex`` (plain lookups, no models): it must
say what ``KnowledgeGraph`` says, and grounding and ``craft explain`` must not need the models at all."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from runtime_fixtures import RuntimeKBs, runtime_kbs_fixture  # noqa: F401

from craft_e.runtime.grounding.energies import (
    required_matrix_from_graph,
    weight_matrices_from_graph,
)
from craft_e.runtime.grounding.explain import explain_pair
from craft_e.runtime.grounding.grounder import ROI, Grounder
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.runtime.kb.graph_index import GraphIndex

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted(p.parent for p in (ROOT / "artifacts" / "kb").glob("*/manifest.json"))


@pytest.mark.parametrize("folder", SHIPPED, ids=[p.name for p in SHIPPED])
def test_the_index_says_what_the_graph_says(folder: Path) -> None:
    bundle = load_bundle(folder, check_encoder=False)
    index, graph, m = bundle.index, bundle.graph, bundle.manifest
    assert index == GraphIndex.from_graph(graph)
    assert index.vp_weights() == graph.vp_weights() and index.po_weights() == graph.po_weights()
    assert index.forbidden_pairs() == graph.forbidden_pairs()
    assert index.object_names == {n.name for n in graph.nodes if n.kind == "object"}
    assert all(index.gloss(o) == graph.gloss(o) for o in m.objects)
    assert all(index.verb_gloss(v) == graph.verb_gloss(v) for v in m.verbs)
    assert all(index.definition(p) == graph.definition(p) for p in m.properties)
    assert all(index.roles(v) == graph.roles(v) for v in m.verbs)
    for a, b in zip(weight_matrices_from_graph(index, m.verbs, m.properties, m.objects),
                    weight_matrices_from_graph(graph, m.verbs, m.properties, m.objects), strict=True):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert np.array_equal(required_matrix_from_graph(index, m.verbs, m.properties),
                          required_matrix_from_graph(graph, m.verbs, m.properties))


def test_grounding_and_its_explanations_never_build_the_models(runtime_kbs: RuntimeKBs) -> None:
    """The models of 150,000 edges take a second to build (``graph_index.py``): loading and
    grounding with an explanation must not, so a robot starts without that second."""
    bundle = load_bundle(runtime_kbs.kb)
    assert bundle.graph_data["edges"] and bundle.index.forbidden_pairs() == [("cut", "umbrella")]
    emb: Any = bundle.embeddings["object"][bundle.object_index["cleaver"]]
    result = Grounder(bundle).ground("cut", [ROI((0, 0, 1, 1), [0.9], image_embedding=emb)])
    assert result.ranked and result.ranked[0].paths
    explained = explain_pair(bundle, "cut", "umbrella")
    assert explained.forbidden and explained.paths == bundle.paths("cut", "umbrella")
    assert "graph" not in vars(bundle)
    assert bundle.graph.forbidden_pairs() == [("cut", "umbrella")]  # on demand, it is still there
    assert "graph" in vars(bundle)
