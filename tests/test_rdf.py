"""The canonical Turtle writer: valid Turtle, the intended triples, deterministic bytes."""

from __future__ import annotations

import networkx as nx
from rdflib import Graph, Literal, URIRef
from rdflib.compare import isomorphic

from craft_e.compiler.rdf import graph_triples, graph_turtle, node_iri


def _graph() -> nx.DiGraph:
    g = nx.DiGraph()
    g.add_node("verb:cut", kind="verb", name="cut")
    g.add_node("prop:has a sharp edge", kind="property", name="has a sharp edge",
               definition='a "thin" edge\\ able to sever\nmaterial')  # fmt: skip
    g.add_node("obj:rubik's cube", kind="object", name="rubik's cube", gloss="a cube puzzle")
    g.add_edge("verb:cut", "prop:has a sharp edge", weight=0.95, relation="llm",
               provenance=["abc"], role="required")  # fmt: skip
    g.add_edge("prop:has a sharp edge", "obj:rubik's cube", weight=0.5, relation="llm",
               provenance=["d", "e"])  # fmt: skip
    return g


def test_turtle_parses_back_to_the_intended_triples() -> None:
    text = graph_turtle(_graph(), "kb-1").decode()
    parsed = Graph().parse(data=text, format="turtle")
    expected = Graph().parse(
        data="\n".join(f"{s} {p} {o} ." for s, p, o in graph_triples(_graph(), "kb-1")),
        format="nt",
    )
    assert isomorphic(parsed, expected)
    prop = URIRef(node_iri("kb-1", "prop:has a sharp edge"))
    comments = list(parsed.objects(prop, URIRef("http://www.w3.org/2000/01/rdf-schema#comment")))
    assert comments == [Literal('a "thin" edge\\ able to sever\nmaterial')]
    assert len(parsed) == 24  # 3 nodes x (type, label) + 2 comments + 2 links x 6 + role + 3 provenance


def test_turtle_is_byte_identical_whatever_the_insertion_order() -> None:
    g = _graph()
    reversed_graph = nx.DiGraph()
    for node in reversed(list(g.nodes)):
        reversed_graph.add_node(node, **g.nodes[node])
    for u, v in reversed(list(g.edges)):
        reversed_graph.add_edge(u, v, **g.edges[u, v])
    assert graph_turtle(g, "kb-1") == graph_turtle(reversed_graph, "kb-1")
