"""What ``craftc validate`` and ``craftc pack`` check beyond loading: the files a build derives
from ``graph.json`` are still its graph's.

Why: ``load_bundle`` (every robot start-up) checks hashes and that the files agree in shape and
range (``runtime/kb/content.py``); it does not recompute what the compiler derived, which costs
more than a start-up should. A KB author validating before a pull request, or signing for robots,
wants to know that ``affordance_energy.npy`` (what the robot ranks by) and ``graph.ttl`` (what
people query) both come from the graph that ``craftc explain`` and ``diff`` show.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..runtime.kb.bundle import Bundle, BundleError, load_bundle
from ..runtime.kb.energy_check import check_energy_matches_graph
from ..runtime.kb.package import unpacked
from .rdf import turtle_of_graph_json


def load_and_check(path: Path, trusted_keys: Sequence[bytes | str] | None = None) -> Bundle:
    """``load_bundle(path)`` (a folder, or a signed ``.craft`` with ``trusted_keys``), then
    :func:`check_derived_files` on the files themselves (a package's, unpacked privately)."""
    bundle = load_bundle(path, check_encoder=False, trusted_keys=trusted_keys)
    if bundle.path.is_dir():
        check_derived_files(bundle)
    else:  # a package: the loaded Bundle names the .craft file, whose unpacked folder is gone
        with unpacked(path, trusted_keys) as (folder, _):
            check_derived_files(load_bundle(folder, check_encoder=False), where=path)
    return bundle


def check_derived_files(bundle: Bundle, where: Path | None = None) -> None:
    """``BundleError`` when E_aff or ``graph.ttl`` is not what the bundle's ``graph.json`` gives.
    ``where``: the bundle as the user named it, for messages (default: its folder)."""
    check_energy_matches_graph(bundle, where)
    ttl = bundle.path / "graph.ttl"
    if ttl.read_bytes() != turtle_of_graph_json(bundle.graph_data, bundle.manifest.kb_name):
        raise BundleError(
            f"{(where or bundle.path) / 'graph.ttl'}: is not the Turtle of graph.json (craftc writes one from the other, byte for "
            "byte); the RDF view is stale or was edited — rebuild the bundle with craftc"
        )
