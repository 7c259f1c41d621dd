"""RDF Turtle export of the graph (rdflib), so the KB opens in any RDF tool.

Weighted edges are reified as ``craft:Link`` resources (subject, object, weight, provenance);
plain ``craft:hasProperty`` / ``craft:propertyOf`` triples are emitted too for simple queries.
"""

from __future__ import annotations

import hashlib
from urllib.parse import quote

import networkx as nx
from rdflib import RDF, RDFS, Graph, Literal, Namespace, URIRef
from rdflib.namespace import XSD

CRAFT = Namespace("https://craft-e.dev/ns#")


def _node_uri(base: Namespace, node_id: str) -> URIRef:
    kind, name = node_id.split(":", 1)
    return URIRef(f"{base}{kind}/{quote(name.replace(' ', '_'), safe='')}")


def graph_turtle(graph: nx.DiGraph, kb_name: str) -> bytes:
    """Deterministic Turtle: rdflib sorts subjects and predicates when serializing."""
    base = Namespace(f"https://craft-e.dev/kb/{kb_name}/")
    rdf = Graph()
    rdf.bind("craft", CRAFT)
    rdf.bind("kb", base)
    kinds = {"verb": CRAFT.Verb, "property": CRAFT.Property, "object": CRAFT.Object}
    for node in sorted(graph.nodes):
        data = graph.nodes[node]
        uri = _node_uri(base, node)
        rdf.add((uri, RDF.type, kinds[data["kind"]]))
        rdf.add((uri, RDFS.label, Literal(data["name"])))
    for u, v in sorted(graph.edges):
        data = graph.edges[u, v]
        su, sv = _node_uri(base, u), _node_uri(base, v)
        predicate = CRAFT.hasProperty if u.startswith("verb:") else CRAFT.propertyOf
        rdf.add((su, predicate, sv))
        link = URIRef(f"{base}link/{hashlib.sha256(f'{u}|{v}'.encode()).hexdigest()[:16]}")
        rdf.add((link, RDF.type, CRAFT.Link))
        rdf.add((link, CRAFT.source, su))
        rdf.add((link, CRAFT.target, sv))
        rdf.add((link, CRAFT.weight, Literal(f"{data['weight']:.6f}", datatype=XSD.decimal)))
        rdf.add((link, CRAFT.relation, Literal(data["relation"])))
        for prov in data["provenance"]:
            rdf.add((link, CRAFT.provenance, Literal(prov)))
    text: str = rdf.serialize(format="turtle")
    return text.encode()
