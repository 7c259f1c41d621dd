"""``graph.json`` of a bundle: the verb -> property -> object graph as node-link JSON.

Node ids are ``verb:<name>``, ``prop:<name>``, ``obj:<name>``; edges go verb -> property (``w_vp``,
with a ``role`` in v2 KBs) and property -> object (``w_po``), each with the record ids it came
from. The compiler writes it (``compiler/graph.py``); everything that reads it — the runtime's
explanations, ``craftc diff`` — goes through :class:`KnowledgeGraph`. A runtime bundle checks
its ``graph.json`` against the same constraints at load (``graph_wire.py``), grounds from plain
lookups of it (``runtime/kb/graph_index.py``) and makes these models only when a reader asks.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from functools import cached_property
from typing import Any, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field, field_validator

GRAPH_SCHEMA_ID = "https://craft-e.dev/schemas/v1/graph.json"

NodeKind = Literal["verb", "property", "object"]
Role = Literal["required", "helpful"]
#: Id prefix of each node kind.
PREFIX: dict[NodeKind, str] = {"verb": "verb:", "property": "prop:", "object": "obj:"}


class GraphNode(BaseModel):
    """A verb, property or object. Properties of v2 KBs carry a ``definition`` fixing their
    sense, objects (and glossed verbs) a ``gloss``; a verb may list ``forbidden_objects`` ("never pick X for V")."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    id: str = Field(pattern=r"^(verb|prop|obj):.+")
    kind: NodeKind
    name: str
    gloss: str | None = None
    definition: str | None = None
    forbidden_objects: list[str] = Field(default_factory=list)


class GraphEdge(BaseModel):
    """verb -> property (``w_vp``) or property -> object (``w_po``), with its provenance."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    source: str = Field(pattern=r"^(verb|prop):.+")
    target: str = Field(pattern=r"^(prop|obj):.+")
    weight: float = Field(ge=0.0, le=1.0, description="w_vp or w_po, in [0, 1]")
    provenance: list[str]
    relation: str | None = None
    role: Role | None = None

    @field_validator("weight", mode="before")
    @classmethod
    def _finite(cls, value: Any) -> Any:
        """A number, never a string or a bool that pydantic would coerce (its range, [0, 1], is
        checked after: every E_aff form assumes it, and the compiler drops any weight outside)."""
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ValueError(f"weight {value!r} is not a finite number")
        return value

    @property
    def verb_property(self) -> bool:
        return self.source.startswith("verb:")

    @property
    def source_name(self) -> str:
        return self.source.split(":", 1)[1]

    @property
    def target_name(self) -> str:
        return self.target.split(":", 1)[1]


class TargetedEdge(Protocol):
    """An edge seen from its source: a ``GraphEdge``, or the runtime's lighter
    ``runtime/kb/graph_index.IndexedEdge`` of the same fields."""

    @property
    def target_name(self) -> str: ...

    @property
    def weight(self) -> float: ...

    @property
    def role(self) -> Role | None: ...


class GroupedEdges(Protocol):
    """A graph whose edges are grouped by source name, in file order."""

    @property
    def verb_properties(self) -> Mapping[str, Sequence[TargetedEdge]]: ...

    @property
    def property_objects(self) -> Mapping[str, Sequence[TargetedEdge]]: ...


class EdgeWeights:
    """The weights and roles of a graph's grouped edges, for ``KnowledgeGraph`` and the
    runtime's ``GraphIndex`` alike (one definition, so the two cannot drift apart)."""

    def vp_weights(self: GroupedEdges) -> dict[tuple[str, str], float]:
        """``(verb, property) -> w_vp`` (the last edge of a pair wins)."""
        return {(v, e.target_name): e.weight for v, es in self.verb_properties.items() for e in es}

    def po_weights(self: GroupedEdges) -> dict[tuple[str, str], float]:
        """``(property, object) -> w_po``."""
        return {(p, e.target_name): e.weight for p, es in self.property_objects.items() for e in es}

    def roles(self: GroupedEdges, verb: str) -> dict[str, Role]:
        """property -> role of ``verb``'s properties that have one (v2 KBs)."""
        return {e.target_name: e.role for e in self.verb_properties.get(verb, []) if e.role is not None}


class KnowledgeGraph(EdgeWeights, BaseModel):
    """The whole graph, with the lookups every reader needs (built once, on first use)."""

    model_config = ConfigDict(extra="forbid", frozen=True, json_schema_extra={"$id": GRAPH_SCHEMA_ID})

    directed: Literal[True] = True
    multigraph: Literal[False] = False
    graph: dict[str, Any] | None = None  # networkx's graph-attribute slot (unused by the compiler)
    nodes: list[GraphNode]
    edges: list[GraphEdge]

    # -- edges -----------------------------------------------------------------------------------

    @cached_property
    def verb_properties(self) -> dict[str, list[GraphEdge]]:
        """verb -> its verb -> property edges, in file order."""
        out: dict[str, list[GraphEdge]] = {}
        for e in self.edges:
            if e.verb_property:
                out.setdefault(e.source_name, []).append(e)
        return out

    @cached_property
    def property_objects(self) -> dict[str, list[GraphEdge]]:
        """property -> its property -> object edges, in file order."""
        out: dict[str, list[GraphEdge]] = {}
        for e in self.edges:
            if not e.verb_property:
                out.setdefault(e.source_name, []).append(e)
        return out

    # -- nodes -----------------------------------------------------------------------------------

    @cached_property
    def node(self) -> dict[str, GraphNode]:
        """id -> node."""
        return {n.id: n for n in self.nodes}

    def definition(self, prop: str) -> str | None:
        node = self.node.get(PREFIX["property"] + prop)
        return None if node is None else node.definition

    def gloss(self, obj: str) -> str | None:
        node = self.node.get(PREFIX["object"] + obj)
        return None if node is None else node.gloss

    def verb_gloss(self, verb: str) -> str | None:
        """The sense a glossed verb was asked in (None for unglossed verbs and older KBs)."""
        node = self.node.get(PREFIX["verb"] + verb)
        return None if node is None else node.gloss

    def forbidden_pairs(self) -> list[tuple[str, str]]:
        """``(verb, object)`` pairs a KB author marked "never pick"."""
        return [(n.name, o) for n in self.nodes if n.kind == "verb" for o in n.forbidden_objects]
