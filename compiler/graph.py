"""Graph pass: draft -> checked networkx graph, its node-link JSON and its RDF Turtle.

Node ids are ``verb:<name>``, ``prop:<name>``, ``obj:<name>``. Checks: weights in [0, 1], no
orphan properties, every verb has at least one property; names are already normalized by the
source passes. Coverage gaps are reported, never padded.
"""

from __future__ import annotations

import json
from typing import Any

import networkx as nx
import numpy as np
import numpy.typing as npt

from ..schemas.v1.bundle import Coverage
from .draft import KnowledgeDraft

K_PROPERTIES = 10
STAGE = "graph_checks"


def check_draft(draft: KnowledgeDraft) -> None:
    """Drop what cannot go into a graph (bad weights, orphan properties), counting why."""
    for verb, props in list(draft.verb_props.items()):
        for prop, link in list(props.items()):
            if not 0.0 <= link.weight <= 1.0:
                del props[prop]
                draft.drop(STAGE, f"{verb} -> {prop}", f"weight out of range: {link.weight}")
    used = set(draft.properties())
    for prop in sorted(set(draft.prop_objs) - used):
        draft.count(
            STAGE, "property-object edges without a verb (not in graph)", len(draft.prop_objs[prop])
        )
        del draft.prop_objs[prop]
    for prop, objs in draft.prop_objs.items():
        for obj, link in list(objs.items()):
            if not 0.0 <= link.weight <= 1.0:
                del objs[obj]
                draft.drop(STAGE, f"{prop} -> {obj}", f"weight out of range: {link.weight}")
    for verb in draft.verbs:
        if not draft.verb_props.get(verb):
            draft.drop(STAGE, verb, "verb without properties: no source answered for it")


def build_graph(draft: KnowledgeDraft) -> nx.DiGraph:
    """A directed graph verb -> property -> object with weight, relation and provenance."""
    graph = nx.DiGraph()
    for verb in draft.verbs:
        graph.add_node(f"verb:{verb}", kind="verb", name=verb)
        if draft.verb_glosses.get(verb):  # the sense the verb was asked in (prompt v3)
            graph.nodes[f"verb:{verb}"]["gloss"] = draft.verb_glosses[verb]
    for obj in draft.objects:
        graph.add_node(f"obj:{obj}", kind="object", name=obj)
        if draft.glosses.get(obj):  # the sense the object was asked in (prompt v2)
            graph.nodes[f"obj:{obj}"]["gloss"] = draft.glosses[obj]
    for prop in draft.properties():
        graph.add_node(f"prop:{prop}", kind="property", name=prop)
        if draft.definitions.get(prop):
            graph.nodes[f"prop:{prop}"]["definition"] = draft.definitions[prop]
    for verb in draft.verbs:
        for prop, link in sorted(draft.verb_props.get(verb, {}).items()):
            graph.add_edge(
                f"verb:{verb}",
                f"prop:{prop}",
                weight=link.weight,
                relation=link.relation,
                provenance=list(link.provenance),
            )
            if link.role:  # "required" | "helpful" (prompt v2)
                graph.edges[f"verb:{verb}", f"prop:{prop}"]["role"] = link.role
    objects = set(draft.objects)
    for prop in draft.properties():
        for obj, link in sorted(draft.prop_objs.get(prop, {}).items()):
            if obj in objects:
                graph.add_edge(
                    f"prop:{prop}",
                    f"obj:{obj}",
                    weight=link.weight,
                    relation=link.relation,
                    provenance=list(link.provenance),
                )
    for verb, obj in sorted(draft.forbidden):
        graph.nodes[f"verb:{verb}"].setdefault("forbidden_objects", []).append(obj)
    return graph


def graph_json(graph: nx.DiGraph) -> bytes:
    """Node-link JSON with sorted nodes and edges: identical graphs give identical bytes."""
    nodes = [{"id": n, **graph.nodes[n]} for n in sorted(graph.nodes)]
    edges = [{"source": u, "target": v, **graph.edges[u, v]} for u, v in sorted(graph.edges)]
    data: dict[str, Any] = {"directed": True, "multigraph": False, "nodes": nodes, "edges": edges}
    return (indented_json(data) + "\n").encode()


_encode_str = json.encoder.encode_basestring  # what json.dumps(ensure_ascii=False) uses (C)


def _float_json(value: float) -> str:
    if value != value or value in (float("inf"), float("-inf")):
        return json.dumps(value)
    return float.__repr__(value)


def _dump(value: Any, depth: int, out: list[str]) -> None:
    if isinstance(value, str):
        out.append(_encode_str(value))
    elif value is None or value is True or value is False:
        out.append("null" if value is None else "true" if value else "false")
    elif isinstance(value, int):
        out.append(int.__repr__(value))
    elif isinstance(value, float):
        out.append(_float_json(value))
    elif isinstance(value, dict):
        if not value:
            out.append("{}")
            return
        if not all(isinstance(k, str) for k in value):
            raise TypeError("non-string key")
        inner = "\n" + " " * (depth + 1)
        sep = "{"
        for key in sorted(value):
            item = value[key]
            kind = type(item)
            if kind is str:  # the common leaves inline: a call per value is most of the cost
                out.append(f"{sep}{inner}{_encode_str(key)}: {_encode_str(item)}")
            elif kind is float and item - item == 0.0:
                out.append(f"{sep}{inner}{_encode_str(key)}: {float.__repr__(item)}")
            else:
                out.append(f"{sep}{inner}{_encode_str(key)}: ")
                _dump(item, depth + 1, out)
            sep = ","
        out.append("\n" + " " * depth + "}")
    elif isinstance(value, list | tuple):
        if not value:
            out.append("[]")
            return
        inner = "\n" + " " * (depth + 1)
        if all(type(item) is str for item in value):
            out.append("[" + inner + ("," + inner).join(map(_encode_str, value)))
        else:
            sep = "["
            for item in value:
                out.append(sep + inner)
                _dump(item, depth + 1, out)
                sep = ","
        out.append("\n" + " " * depth + "]")
    else:
        raise TypeError(f"not JSON: {type(value).__name__}")


def indented_json(data: Any) -> str:
    """``json.dumps(data, indent=1, sort_keys=True, ensure_ascii=False)``, byte for byte, in a
    fraction of the time: with ``indent`` json falls back to its pure-Python encoder (seconds
    for a 10,000-object graph); here only the layout is Python, strings go through json's C
    escaper. Anything unusual (non-string keys, other types) takes json.dumps itself."""
    out: list[str] = []
    try:
        _dump(data, 0, out)
    except TypeError:
        return json.dumps(data, indent=1, sort_keys=True, ensure_ascii=False)
    return "".join(out)


def weight_matrices(
    draft: KnowledgeDraft, properties: list[str]
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """``w_vp [V, P]`` and ``w_po [P, O]`` in manifest order; forbidden pairs handled later."""
    p_index = {p: i for i, p in enumerate(properties)}
    o_index = {o: i for i, o in enumerate(draft.objects)}
    w_vp = np.zeros((len(draft.verbs), len(properties)), dtype=np.float32)
    w_po = np.zeros((len(properties), len(draft.objects)), dtype=np.float32)
    for vi, verb in enumerate(draft.verbs):
        for prop, link in draft.verb_props.get(verb, {}).items():
            w_vp[vi, p_index[prop]] = link.weight
    for prop, objs in draft.prop_objs.items():
        if prop in p_index:
            for obj, link in objs.items():
                if obj in o_index:
                    w_po[p_index[prop], o_index[obj]] = link.weight
    return w_vp, w_po


def coverage(draft: KnowledgeDraft, energy: npt.NDArray[np.float32]) -> Coverage:
    """Gaps a KB author should see: thin verbs, property-less and unreachable objects."""
    with_props = {o for objs in draft.prop_objs.values() for o in objs}
    reachable = energy.min(axis=0) < 0 if energy.size else np.zeros(len(draft.objects), bool)
    verb_reach = energy.min(axis=1) < 0 if energy.size else np.zeros(len(draft.verbs), bool)
    return Coverage(
        verbs_with_fewer_than_k_properties={
            v: len(draft.verb_props.get(v, {}))
            for v in draft.verbs
            if len(draft.verb_props.get(v, {})) < K_PROPERTIES
        },
        objects_without_properties=[o for o in draft.objects if o not in with_props],
        objects_unreachable_from_any_verb=[
            o for i, o in enumerate(draft.objects) if not reachable[i]
        ],
        verbs_reaching_no_object=[v for i, v in enumerate(draft.verbs) if not verb_reach[i]],
    )
