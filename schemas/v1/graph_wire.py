"""``graph.json`` checked as plain data: every constraint of :class:`KnowledgeGraph`, no models.

Why: loading a bundle validates its graph (a weight that is a string, a missing edge list, an id
that is not ``<kind>:<name>`` is refused at load, naming the file: issue 12). Validating it as
``KnowledgeGraph`` builds one pydantic model per node and edge; at 1,000 verbs x 10,000 objects
(150,000 edges) that, with ``json.loads`` before it, was 1.9 s of a 2.6 s load
(``benchmarks/bench_scale.py``; issue 14's target is 1 s). The same constraints written as
``TypedDict`` s are checked by pydantic-core while it parses the JSON bytes, into plain dicts, in
a quarter of that time. Grounding reads those dicts (``runtime/kb/graph_index.py``); the models
are made only for a reader that asks for them (``Bundle.graph``).

The two descriptions must accept and refuse the same documents: ``tests/test_graph_wire.py``
holds them to it.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, NotRequired

from pydantic import ConfigDict, Field, TypeAdapter, ValidationError, with_config
from typing_extensions import TypedDict  # pydantic needs this one before Python 3.12

from .graph import NodeKind, Role

__all__ = ["GraphWire", "ValidationError", "graph_wire_problem", "validate_graph_json"]

_FORBID = ConfigDict(extra="forbid")
#: A weight is a JSON number, finite, in [0, 1]; never a string or a bool (as ``GraphEdge``).
_Weight = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0.0, le=1.0)]
#: pydantic's error types of a number outside ``ge`` / ``le``.
_OUT_OF_RANGE = ("greater_than_equal", "less_than_equal")


@with_config(_FORBID)
class NodeWire(TypedDict):
    """``GraphNode`` as plain data."""

    id: Annotated[str, Field(pattern=r"^(verb|prop|obj):.+")]
    kind: NodeKind
    name: str
    gloss: NotRequired[str | None]
    definition: NotRequired[str | None]
    forbidden_objects: NotRequired[list[str]]


@with_config(_FORBID)
class EdgeWire(TypedDict):
    """``GraphEdge`` as plain data."""

    source: Annotated[str, Field(pattern=r"^(verb|prop):.+")]
    target: Annotated[str, Field(pattern=r"^(prop|obj):.+")]
    weight: _Weight
    provenance: list[str]
    relation: NotRequired[str | None]
    role: NotRequired[Role | None]


@with_config(_FORBID)
class GraphWire(TypedDict):
    """``KnowledgeGraph`` as plain data."""

    directed: NotRequired[Literal[True]]
    multigraph: NotRequired[Literal[False]]
    graph: NotRequired[dict[str, Any] | None]
    nodes: list[NodeWire]
    edges: list[EdgeWire]


_ADAPTER: TypeAdapter[GraphWire] = TypeAdapter(GraphWire)


def validate_graph_json(data: bytes | str) -> GraphWire:
    """``graph.json``'s bytes parsed and checked in one pass; raises ``ValidationError`` (a
    ``ValueError``) on a malformed document or a broken constraint."""
    return _ADAPTER.validate_json(data)


def graph_wire_problem(exc: ValidationError) -> str:
    """The first fault of ``exc`` in ``KnowledgeGraph``'s words: where, and what is wrong (a
    weight that is no finite number is said so, as the model's own check says it; one outside
    [0, 1] too)."""
    first = exc.errors()[0]
    where = ".".join(str(p) for p in first["loc"]) or "graph"
    if first["loc"] and first["loc"][-1] == "weight" and first["type"] in _OUT_OF_RANGE:
        return f"{where!r}: weight {first['input']!r} is outside [0, 1], where weights lie"
    if first["loc"] and first["loc"][-1] == "weight" and first["type"] != "missing":
        return f"{where!r}: weight {first['input']!r} is not a finite number"
    return f"{where!r}: {first['msg']}"

