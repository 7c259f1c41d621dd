"""``graph.json`` checked as plain data (``schemas/v1/graph_wire.py``) accepts and refuses what
``KnowledgeGraph`` does, and the graph made of what it accepts is ``KnowledgeGraph``'s."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from craft_e.schemas.v1.graph import KnowledgeGraph
from craft_e.schemas.v1.graph_wire import graph_wire_problem, validate_graph_json

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted((ROOT / "artifacts" / "kb").glob("*/graph.json"))

Doc = dict[str, Any]


def tiny() -> Doc:
    """Every field a graph may have: glosses, a definition, a forbidden object, roles, a relation."""
    return {
        "directed": True,
        "multigraph": False,
        "graph": {},
        "nodes": [
            {"id": "verb:cut", "kind": "verb", "name": "cut", "gloss": "separate with a blade",
             "forbidden_objects": ["umbrella"]},
            {"id": "prop:sharp edge", "kind": "property", "name": "sharp edge", "definition": "a thin hard edge"},
            {"id": "obj:knife", "kind": "object", "name": "knife", "gloss": "a blade with a handle"},
            {"id": "obj:umbrella", "kind": "object", "name": "umbrella"},
        ],
        "edges": [
            {"source": "verb:cut", "target": "prop:sharp edge", "weight": 0.9, "provenance": ["r1"],
             "role": "required"},
            {"source": "prop:sharp edge", "target": "obj:knife", "weight": 1, "provenance": ["r2", "r3"],
             "relation": "HasProperty", "role": None},
        ],
    }


def _set(path: tuple[Any, ...], value: Any) -> Callable[[Doc], None]:
    def edit(doc: Doc) -> None:
        target = doc
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
    return edit


def _drop(path: tuple[Any, ...]) -> Callable[[Doc], None]:
    def edit(doc: Doc) -> None:
        target = doc
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]
    return edit


#: (id, edit of ``tiny()``, accepted) — the faults issue 12 refuses at load, and their neighbours
CASES: list[tuple[str, Callable[[Doc], None], bool]] = [
    ("as-is", lambda d: None, True),
    ("int-weight", _set(("edges", 0, "weight"), 1), True),
    ("no-optional-fields", lambda d: [_drop(("nodes", 0, "gloss"))(d), _drop(("nodes", 0, "forbidden_objects"))(d),
                                      _drop(("edges", 0, "role"))(d), _drop(("directed",))(d),
                                      _drop(("multigraph",))(d), _drop(("graph",))(d)], True),
    ("graph-null", _set(("graph",), None), True),
    ("zero-weight", _set(("edges", 0, "weight"), 0), True),
    ("weight-above-1", _set(("edges", 0, "weight"), 1.5), False),
    ("negative-weight", _set(("edges", 1, "weight"), -0.1), False),
    ("string-weight", _set(("edges", 0, "weight"), "0.9"), False),
    ("bool-weight", _set(("edges", 0, "weight"), True), False),
    ("null-weight", _set(("edges", 0, "weight"), None), False),
    ("no-weight", _drop(("edges", 0, "weight")), False),
    ("no-edges", _drop(("edges",)), False),
    ("no-nodes", _drop(("nodes",)), False),
    ("edges-not-list", _set(("edges",), {}), False),
    ("extra-edge-key", _set(("edges", 0, "colour"), "red"), False),
    ("extra-node-key", _set(("nodes", 0, "colour"), "red"), False),
    ("extra-top-key", _set(("colour",), "red"), False),
    ("source-an-object", _set(("edges", 0, "source"), "obj:knife"), False),
    ("target-a-verb", _set(("edges", 0, "target"), "verb:cut"), False),
    ("source-no-name", _set(("edges", 0, "source"), "verb:"), False),
    ("node-id-no-prefix", _set(("nodes", 0, "id"), "cut"), False),
    ("bad-kind", _set(("nodes", 0, "kind"), "tool"), False),
    ("bad-role", _set(("edges", 0, "role"), "optional"), False),
    ("provenance-a-string", _set(("edges", 0, "provenance"), "r1"), False),
    ("provenance-item-int", _set(("edges", 0, "provenance"), [1]), False),
    ("forbidden-a-string", _set(("nodes", 0, "forbidden_objects"), "umbrella"), False),
    ("name-int", _set(("nodes", 0, "name"), 3), False),
    ("gloss-int", _set(("nodes", 0, "gloss"), 3), False),
    ("relation-int", _set(("edges", 1, "relation"), 3), False),
    ("undirected", _set(("directed",), False), False),
    ("multigraph", _set(("multigraph",), True), False),
    ("graph-a-list", _set(("graph",), []), False),
    ("edge-a-list", _set(("edges", 0), ["verb:cut", "prop:sharp edge"]), False),
]


def _model_accepts(text: str) -> KnowledgeGraph | None:
    try:
        return KnowledgeGraph.model_validate(json.loads(text))
    except ValidationError:
        return None


@pytest.mark.parametrize(("edit", "accepted"), [(e, a) for _, e, a in CASES], ids=[c[0] for c in CASES])
def test_the_plain_check_accepts_and_refuses_what_the_model_does(edit: Callable[[Doc], None], accepted: bool) -> None:
    doc = tiny()
    edit(doc)
    text = json.dumps(doc)
    model = _model_accepts(text)
    assert (model is not None) is accepted
    if not accepted:
        with pytest.raises(ValidationError):
            validate_graph_json(text)
        return
    data = validate_graph_json(text)
    assert KnowledgeGraph.model_validate(data) == model


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity", "1e999"])
def test_a_weight_that_is_no_finite_number_is_refused_by_both(token: str) -> None:
    text = json.dumps(tiny()).replace('"weight": 0.9', f'"weight": {token}')
    assert token in text
    assert _model_accepts(text) is None
    with pytest.raises(ValidationError) as info:
        validate_graph_json(text)
    assert "not a finite number" in graph_wire_problem(info.value)


@pytest.mark.parametrize("weight", [5.0, -1.0])
def test_a_weight_outside_0_1_is_named_by_both(weight: float) -> None:
    doc = tiny()
    doc["edges"][1]["weight"] = weight
    said = f"'edges.1.weight': weight {weight!r} is outside [0, 1], where weights lie"
    with pytest.raises(ValidationError) as info:
        validate_graph_json(json.dumps(doc))
    assert graph_wire_problem(info.value) == said
    with pytest.raises(ValidationError) as info:
        KnowledgeGraph.model_validate(doc)
    assert graph_wire_problem(info.value) == said


def test_the_fault_is_named_where_it_is() -> None:
    doc = tiny()
    doc["edges"][1]["weight"] = "0.9"
    with pytest.raises(ValidationError) as info:
        validate_graph_json(json.dumps(doc))
    assert graph_wire_problem(info.value) == "'edges.1.weight': weight '0.9' is not a finite number"
    del doc["edges"]
    with pytest.raises(ValidationError) as info:
        validate_graph_json(json.dumps(doc))
    assert graph_wire_problem(info.value) == "'edges': Field required"


def test_malformed_json_is_refused() -> None:
    with pytest.raises(ValidationError):
        validate_graph_json(b'{"nodes": [], "edges": [')


@pytest.mark.parametrize("path", SHIPPED, ids=[p.parent.name for p in SHIPPED])
def test_every_shipped_graph_reads_the_same_both_ways(path: Path) -> None:
    raw = path.read_bytes()
    assert KnowledgeGraph.model_validate(validate_graph_json(raw)) == KnowledgeGraph.model_validate(json.loads(raw))

