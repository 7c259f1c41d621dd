"""What grounding reads of a bundle's graph, as plain lookups made in one pass over its data.

Why: a grounder needs the graph's weights as matrices, each verb's properties and each
property's objects (for explanations), the objects it names and the "never pick" pairs; it
never needs one pydantic model per edge. At 1,000 verbs x 10,000 objects (150,000 edges) building
the :class:`KnowledgeGraph` models takes 1.2 s, these lookups 0.3 s, from the same checked data
(``schemas/v1/graph_wire.py``). ``Bundle.index`` holds them; ``Bundle.graph`` still gives the
whole model to the readers that want node texts or every edge (``craft explain``, diagnostics,
the evaluations). The two agree on everything here (``tests/test_graph_index.py``).

``craft explain`` reads its glosses and definitions here too: one explanation of a large KB
should not build every edge's model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from ...schemas.v1.graph import PREFIX, EdgeWeights, GraphEdge, KnowledgeGraph, Role
from ...schemas.v1.graph_wire import GraphWire


class IndexedEdge(NamedTuple):
    """A verb -> property or property -> object edge, seen from its source (``GraphEdge``'s
    fields of the same names)."""

    target_name: str
    weight: float
    provenance: list[str]
    role: Role | None


@dataclass(frozen=True)
class GraphIndex(EdgeWeights):
    """Edges grouped by source name, in file order (as ``KnowledgeGraph.verb_properties`` and
    ``property_objects``), the object names, the "never pick" pairs and each node's texts; the
    weights and roles come from ``EdgeWeights``, as ``KnowledgeGraph``'s do."""

    verb_properties: dict[str, list[IndexedEdge]]
    property_objects: dict[str, list[IndexedEdge]]
    object_names: frozenset[str]
    forbidden: tuple[tuple[str, str], ...]
    #: node id -> (gloss, definition), the last node of an id winning (as ``KnowledgeGraph.node``)
    texts: dict[str, tuple[str | None, str | None]]

    @classmethod
    def from_wire(cls, data: GraphWire) -> GraphIndex:
        """From ``graph.json`` as ``validate_graph_json`` checked it."""
        vp: dict[str, list[IndexedEdge]] = {}
        po: dict[str, list[IndexedEdge]] = {}
        new = tuple.__new__
        for e in data["edges"]:
            kind, _, source = e["source"].partition(":")
            # tuple.__new__: a NamedTuple's own constructor is a Python call, a third of this loop
            edge = new(IndexedEdge, (e["target"].partition(":")[2], e["weight"], e["provenance"], e.get("role")))
            (vp if kind == "verb" else po).setdefault(source, []).append(edge)
        objects = frozenset(n["name"] for n in data["nodes"] if n["kind"] == "object")
        forbidden = tuple((n["name"], o) for n in data["nodes"] if n["kind"] == "verb"
                          for o in n.get("forbidden_objects", []))
        texts = {n["id"]: (n.get("gloss"), n.get("definition")) for n in data["nodes"]}
        return cls(vp, po, objects, forbidden, texts)

    @classmethod
    def from_graph(cls, graph: KnowledgeGraph) -> GraphIndex:
        """From the models (the same lookups as ``from_wire`` of the same document)."""
        def group(edges: dict[str, list[GraphEdge]]) -> dict[str, list[IndexedEdge]]:
            return {s: [IndexedEdge(e.target_name, e.weight, e.provenance, e.role) for e in es]
                    for s, es in edges.items()}

        return cls(group(graph.verb_properties), group(graph.property_objects),
                   frozenset(n.name for n in graph.nodes if n.kind == "object"),
                   tuple(graph.forbidden_pairs()), {n.id: (n.gloss, n.definition) for n in graph.nodes})

    def forbidden_pairs(self) -> list[tuple[str, str]]:
        """``(verb, object)`` pairs a KB author marked "never pick"."""
        return list(self.forbidden)

    def definition(self, prop: str) -> str | None:
        return self.texts.get(PREFIX["property"] + prop, (None, None))[1]

    def gloss(self, obj: str) -> str | None:
        return self.texts.get(PREFIX["object"] + obj, (None, None))[0]

    def verb_gloss(self, verb: str) -> str | None:
        """The sense a glossed verb was asked in (None for unglossed verbs and older KBs)."""
        return self.texts.get(PREFIX["verb"] + verb, (None, None))[0]
