"""A bundle's files checked against each other and against its manifest, once their hashes match.

Why: hashes prove that the files are the ones the manifest lists, not that they agree. A bundle
written by a buggy or hostile tool, or edited and resealed, can hash consistently and still hold
an edge to a node that does not exist, a weight of 5, E_aff = +7, one object listed twice, a verb
the runtime is never asked for ("CUT"), a text encoder no image encoder embeds into, or an
``open_world.json`` the grounder cannot read: the robot would then refuse it at its first request,
or rank by garbage without a word. ``verify.verify_files`` (``craft install``, unpacking a
package), ``bundle.bundle_from_files`` (``craftc pack``) and ``bundle.load_bundle`` (``craftc
validate`` and every command that loads a bundle) run :func:`read_content`, so such a bundle never verifies, is never signed or
installed. Each fault is a ``BundleError`` naming the file, the record and the fix.

Loading parses every file anyway; the checks add one pass over the graph's nodes and edges and a
few vectorised reductions of E_aff (bundle loading is on the robot's start-up path).
"""

from __future__ import annotations

import io
import json
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from itertools import repeat
from operator import itemgetter
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from pydantic import ValidationError
from safetensors import SafetensorError

from ...schemas.names import is_normalized, normalize_name, normalize_verb, shown
from ...schemas.v1.bundle import MANIFEST_FILE, BundleReport, Manifest
from ...schemas.v1.graph import PREFIX, NodeKind
from ...schemas.v1.graph_wire import GraphWire, graph_wire_problem, validate_graph_json
from ...schemas.v1.open_world import OpenWorld
from ..encoders import REGISTRY
from ..encoders.conse import imagenet_class_index
from ..encoders.text import MINILM_ID
from ..grounding.energies import FORBIDDEN_ENERGY
from .colours import COLOURS_FILE, TypicalColours, parse_colours
from .errors import BundleError
from .lookalikes import LOOKALIKES_FILE, Lookalikes, parse_lookalikes
from .sizes import SIZES_FILE, SizesError, TypicalSize, parse_sizes

__all__ = ["BundleContent", "check_content", "check_graph", "check_manifest", "read_content",
           "text_spaces"]

FloatArray = npt.NDArray[np.float32]
GRAPH_FILE = "graph.json"
ENERGY_FILE = "affordance_energy.npy"
EMBEDDINGS_FILE = "embeddings.safetensors"
REPORT_FILE = "report.json"
OPEN_WORLD_FILE = "open_world.json"
REBUILD = "rebuild the bundle with craftc"
#: Every E_aff form lies in [-1, 0] (``grounding/energies.py``: ``tanh`` of a non-positive sum, or
#: a normalized product of weights in [0, 1]); a float32 of a float64 -1 may land this far below.
ENERGY_FLOOR_SLACK = 1e-5
#: The graph's edges: verb -> property (``w_vp``) and property -> object (``w_po``).
EDGE_KINDS: frozenset[tuple[str, str]] = frozenset({("verb", "property"), ("property", "object")})
#: manifest axis -> node kind and the normalizer the runtime looks names of that axis up with
#: (None: not normalized; properties of a direct-mode bundle are "direct: <verb>").
_AXES: tuple[tuple[str, NodeKind, Callable[[str], str] | None], ...] = (
    ("verbs", "verb", normalize_verb),
    ("objects", "object", normalize_name),
    ("properties", "property", None),
)


@dataclass(frozen=True)
class BundleContent:
    """A bundle's files, parsed and checked (``load_bundle`` keeps them)."""

    graph: GraphWire
    energy: npt.NDArray[np.floating[Any]]  # [V, O] E_aff as stored (float32 from craftc)
    embeddings: dict[str, FloatArray]
    report: BundleReport
    open_world: dict[str, Any] | None
    sizes: dict[str, TypicalSize]
    colours: dict[str, TypicalColours]
    lookalikes: dict[str, Lookalikes]


def text_spaces() -> frozenset[str]:
    """The text encoder ids some registered image encoder embeds into (``encoders.REGISTRY``):
    a bundle in any other space could never be grounded by ``craft ground``, ``serve`` or ``sim``."""
    return frozenset(e.text_space for e in REGISTRY.values() if e.text_space)


def read_content(
    folder: Path, manifest: Manifest, data: dict[str, bytes], *, text_space: str | None = None
) -> BundleContent:
    """Parse the bundle's files (``data``: name -> bytes, hashes already checked) and check them
    against each other and the manifest; a ``BundleError`` names the first fault.

    ``text_space``: a text encoder id the caller embeds with (``load_bundle(encoder_id=...)``),
    accepted besides the registered ones, for a caller bringing its own encoder.
    """
    check_manifest(folder, manifest, text_space=text_space)
    try:
        graph = validate_graph_json(data[GRAPH_FILE])
    except ValidationError as exc:  # malformed JSON, or a constraint of the graph broken
        raise BundleError(f"{folder / GRAPH_FILE}: {graph_wire_problem(exc)}; rebuild the bundle") from None
    forbidden = check_graph(folder, manifest, graph)
    energy = _parse(folder, ENERGY_FILE, lambda b: np.load(io.BytesIO(b), allow_pickle=False), data)
    embeddings = _parse(folder, EMBEDDINGS_FILE, _load_embeddings, data)
    check_content(folder, manifest, energy, embeddings, forbidden)
    _check_embedding_index(folder, manifest, data[EMBEDDINGS_FILE])
    report = _parse(folder, REPORT_FILE, BundleReport.model_validate_json, data)
    open_world = _parse(folder, OPEN_WORLD_FILE, _open_world, data) if OPEN_WORLD_FILE in data else None
    try:
        sizes = parse_sizes(folder, data[SIZES_FILE], manifest.objects) if SIZES_FILE in data else {}
        colours = (parse_colours(folder, data[COLOURS_FILE], manifest.objects)
                   if COLOURS_FILE in data else {})
        lookalikes = (parse_lookalikes(folder, data[LOOKALIKES_FILE], manifest.objects,
                                       imagenet_class_index().keys())
                      if LOOKALIKES_FILE in data else {})
    except SizesError as exc:  # ColoursError and LookalikesError are ones
        raise BundleError(str(exc)) from None
    return BundleContent(graph, energy, embeddings, report, open_world, sizes, colours, lookalikes)


def _parse(folder: Path, name: str, parse: Callable[[bytes], Any], data: dict[str, bytes]) -> Any:
    """``parse(data[name])``, or a ``BundleError`` naming the file and, for a model, the field."""
    try:
        return parse(data[name])
    except ValidationError as exc:
        first = exc.errors()[0]
        field = ".".join(str(p) for p in first["loc"])
        where = f"{field}: " if field else ""
        raise BundleError(f"{folder / name}: {where}{first['msg']}; rebuild the bundle") from None
    except (ValueError, KeyError, TypeError, RecursionError, OSError, EOFError, SafetensorError) as exc:
        raise BundleError(f"{folder / name}: does not parse ({exc}); rebuild the bundle") from None


def _load_embeddings(blob: bytes) -> dict[str, FloatArray]:
    from safetensors.numpy import load as load_safetensors

    return {k: np.asarray(v, dtype=np.float32) for k, v in load_safetensors(blob).items()}


def _open_world(blob: bytes) -> dict[str, Any]:
    """``open_world.json`` as the grounder reads it (a dict), checked against :class:`OpenWorld`."""
    raw = json.loads(blob)
    if not isinstance(raw, dict):
        raise ValueError("not a JSON object")
    OpenWorld.model_validate(raw)
    return raw


# -- the manifest ---------------------------------------------------------------------------------


def check_manifest(folder: Path, manifest: Manifest, *, text_space: str | None = None) -> None:
    """Axes without repeats, in the normalized form the runtime looks names up in; a text encoder
    some image encoder embeds into; a verb template with a ``{verb}`` field."""
    where = folder / MANIFEST_FILE
    for axis, _, normalize in _AXES:
        names: list[str] = getattr(manifest, axis)
        if len(set(names)) != len(names):
            seen: set[str] = set()
            for i, name in enumerate(names):
                if name in seen:
                    raise BundleError(
                        f"{where}: {axis}[{i}] {shown(name)} is listed twice; each name is one "
                        f"row or column of E_aff and the embeddings — {REBUILD}"
                    )
                seen.add(name)
        if normalize is None:
            continue
        singular = normalize is normalize_name
        for i, name in enumerate(names):
            if not is_normalized(name, singular=singular):
                try:
                    form = f"; normalized it is {normalize(name)!r}"
                except ValueError as exc:
                    form = f" ({exc})"
                raise BundleError(
                    f"{where}: {axis}[{i}] {shown(name)} is not in the normalized form the runtime "
                    f"looks {axis} up in (lowercase, single spaces{', singular' if singular else ''})"
                    f"{form}, so no request could reach it — {REBUILD}, which normalizes every name"
                )
    enc = manifest.text_encoder
    known = text_spaces() | ({text_space} if text_space else set())
    if enc.id not in known:
        raise BundleError(
            f"{where}: text_encoder.id {shown(enc.id)} is not a text space any image encoder of "
            f"this runtime embeds into ({', '.join(sorted(known))}), so it could never ground with "
            f"this bundle — {REBUILD}, which embeds with {MINILM_ID}"
        )
    try:
        probe = enc.verb_template.format(verb="\x00")
    except (KeyError, IndexError, ValueError, AttributeError):
        probe = ""
    if "\x00" not in probe:
        raise BundleError(
            f"{where}: text_encoder.verb_template {shown(enc.verb_template)} is not a template "
            "with one {verb} field (e.g. 'something to {verb}'); the runtime embeds requests "
            f"through it — {REBUILD}"
        )


# -- the graph ------------------------------------------------------------------------------------


def check_graph(folder: Path, manifest: Manifest, graph: GraphWire) -> list[tuple[int, int]]:
    """Each node once, its id ``<kind>:<name>``; the nodes of each kind exactly the manifest's
    axis; every edge verb -> property or property -> object between existing nodes, once (its
    weight in [0, 1] was checked while parsing); "never pick" objects on verbs only, each an
    object of the bundle.

    Returns the "never pick" pairs as (verb row, object column) of E_aff, which must hold
    ``FORBIDDEN_ENERGY`` there and nowhere else (``check_content``).
    """
    where = folder / GRAPH_FILE
    kinds: dict[str, str] = {}
    for i, node in enumerate(graph["nodes"]):
        nid, kind = node["id"], node["kind"]
        if nid in kinds:
            raise BundleError(f"{where}: nodes[{i}] {shown(nid)} appears twice; each node is "
                              f"listed once — {REBUILD}")
        if nid != PREFIX[kind] + node["name"]:
            raise BundleError(f"{where}: nodes[{i}] has id {shown(nid)} but kind {kind!r} and name "
                              f"{shown(node['name'])} (expected {shown(PREFIX[kind] + node['name'])}) — {REBUILD}")
        kinds[nid] = kind
    per_kind = Counter(kinds.values())
    for axis, kind, _ in _AXES:
        names: list[str] = getattr(manifest, axis)
        prefix = PREFIX[kind]
        missing = [n for n in names if kinds.get(prefix + n) != kind]
        if missing:
            raise BundleError(
                f"{where}: has no node {shown(prefix + missing[0])}, yet the manifest lists "
                f"{kind} {shown(missing[0])} ({len(missing)} of its {len(names)} {axis} have no "
                f"node); the graph and the manifest are not of one build — {REBUILD}"
            )
        if per_kind[kind] != len(names):
            listed = set(names)
            extra = next(nid for nid, k in kinds.items() if k == kind and nid[len(prefix):] not in listed)
            raise BundleError(f"{where}: node {shown(extra)} is not one of the manifest's {axis}; "
                              f"the graph and the manifest are not of one build — {REBUILD}")
    _check_edges(where, graph, kinds)
    return _forbidden_cells(where, manifest, graph)


#: Node kinds as numbers for the vectorised edge check (``_NO_NODE``: an id no node has).
_KIND_CODE: dict[str, int] = {"verb": 0, "property": 1, "object": 2}
_NO_NODE = 3
_EDGE_CODES = (_KIND_CODE["verb"] * 4 + _KIND_CODE["property"],
               _KIND_CODE["property"] * 4 + _KIND_CODE["object"])


def _check_edges(where: Path, graph: GraphWire, kinds: dict[str, str]) -> None:
    """Every edge verb -> property or property -> object, between nodes of the graph, once (its
    weight's range, [0, 1], is checked while parsing: ``graph_wire``).

    Node ids become numbers in C (``map`` / ``fromiter``) and the checks are array operations:
    at 150,000 edges 40 ms, where a Python loop over the edges took 110 ms of a start-up. Only
    when one fails are the edges walked, to name the first bad one.
    """
    edges = graph["edges"]
    ids = {nid: i for i, nid in enumerate(kinds)}
    codes = np.array([*(_KIND_CODE[k] for k in kinds.values()), _NO_NODE], dtype=np.int64)
    n = len(edges)
    src = np.fromiter(map(ids.get, map(itemgetter("source"), edges), repeat(-1)), np.int64, n)
    dst = np.fromiter(map(ids.get, map(itemgetter("target"), edges), repeat(-1)), np.int64, n)
    links = codes[src] * 4 + codes[dst]  # -1 (no such node) picks _NO_NODE, the last code
    pairs = np.sort(src * (len(ids) + 1) + dst)
    if np.isin(links, _EDGE_CODES).all() and not (pairs[1:] == pairs[:-1]).any():
        return
    seen: set[tuple[str, str]] = set()
    for i, edge in enumerate(edges):
        source, target = edge["source"], edge["target"]
        link = (kinds.get(source), kinds.get(target))
        if link not in EDGE_KINDS:
            what = (f"{shown(source if link[0] is None else target)} is not a node of the graph"
                    if None in link else f"it goes {link[0]} -> {link[1]}; edges go verb -> "
                    "property or property -> object")
            raise BundleError(f"{where}: edges[{i}] {shown(source)} -> {shown(target)}: {what} — {REBUILD}")
        if (source, target) in seen:
            raise BundleError(f"{where}: edges[{i}] {shown(source)} -> {shown(target)} appears "
                              f"twice; each pair is linked once, with one weight — {REBUILD}")
        seen.add((source, target))


def _forbidden_cells(where: Path, manifest: Manifest, graph: GraphWire) -> list[tuple[int, int]]:
    """The "never pick" pairs as E_aff cells; each names an object of the bundle, on a verb node."""
    rows = {v: i for i, v in enumerate(manifest.verbs)}
    columns: dict[str, int] | None = None
    cells: list[tuple[int, int]] = []
    for i, node in enumerate(graph["nodes"]):
        objects = node.get("forbidden_objects")
        if not objects:
            continue
        if node["kind"] != "verb":
            raise BundleError(f"{where}: nodes[{i}] {shown(node['id'])} lists forbidden_objects; only a "
                              f"verb can forbid objects — {REBUILD}")
        columns = columns if columns is not None else {o: j for j, o in enumerate(manifest.objects)}
        for obj in objects:
            if obj not in columns:
                raise BundleError(f"{where}: nodes[{i}] {shown(node['id'])} forbids {shown(obj)}, which "
                                  f"is not an object of the bundle — {REBUILD}")
            cells.append((rows[node["name"]], columns[obj]))
    return cells


# -- E_aff and the embeddings ---------------------------------------------------------------------


def check_content(
    folder: Path,
    manifest: Manifest,
    energy: npt.NDArray[Any],
    embeddings: dict[str, FloatArray],
    forbidden: Sequence[tuple[int, int]] = (),
) -> None:
    """Values and shapes a grounder relies on; consistent hashes do not make content sane.

    E_aff is ``[V, O]``, finite, in [-1, 0] but for the "never pick" cells (``forbidden``, from
    the graph), which hold ``FORBIDDEN_ENERGY``; each embedding tensor has one finite row per
    name of its axis, as wide as the manifest's text encoder embeds.
    """
    where = folder / ENERGY_FILE
    v, o = len(manifest.verbs), len(manifest.objects)
    if energy.shape != (v, o):
        raise BundleError(f"{where}: shape {energy.shape}, manifest says ({v}, {o})")
    if energy.dtype.kind != "f" or not np.isfinite(energy).all():
        raise BundleError(f"{where}: holds NaN, infinite or non-float values; rebuild the bundle")
    if energy.size:
        _check_energy_range(where, manifest, energy, forbidden)
    dim = manifest.text_encoder.dim
    for key, rows in (
        ("verb", v),
        ("verb_query", v),
        ("object", o),
        ("property", len(manifest.properties)),
    ):
        if key not in embeddings or embeddings[key].ndim != 2 or embeddings[key].shape[0] != rows:
            raise BundleError(
                f"{folder / EMBEDDINGS_FILE}: tensor {key!r} missing or not {rows} rows"
            )
        if embeddings[key].shape[1] != dim:
            raise BundleError(
                f"{folder / EMBEDDINGS_FILE}: tensor {key!r} is {embeddings[key].shape[1]} "
                f"wide, the manifest's text encoder embeds into {dim}; rebuild the bundle"
            )
        if not np.isfinite(embeddings[key]).all():
            raise BundleError(
                f"{folder / EMBEDDINGS_FILE}: tensor {key!r} holds NaN or infinite "
                "values; rebuild the bundle"
            )
        zero = np.flatnonzero(~embeddings[key].any(axis=1))
        if zero.size:  # a text encoder gives unit vectors: a zero row aligns with nothing, silently
            axis = {"verb": manifest.verbs, "verb_query": manifest.verbs, "object": manifest.objects,
                    "property": manifest.properties}[key]
            raise BundleError(
                f"{folder / EMBEDDINGS_FILE}: tensor {key!r} row {int(zero[0])} "
                f"({shown(axis[int(zero[0])])}) is all zeros; a text embedding never is — {REBUILD}"
            )


def _check_energy_range(
    where: Path, manifest: Manifest, energy: npt.NDArray[Any], forbidden: Sequence[tuple[int, int]]
) -> None:
    def cell(i: int, j: int) -> str:
        return f"E_aff({manifest.verbs[i]!r}, {manifest.objects[j]!r}) = {float(energy[i, j]):g}"

    rule = (f"every E_aff form lies in [-1, 0], and only a pair the graph marks \"never pick\" "
            f"holds {FORBIDDEN_ENERGY:+g}")
    low = np.unravel_index(int(np.argmin(energy)), energy.shape)
    if energy[low] < -1.0 - ENERGY_FLOOR_SLACK:
        raise BundleError(f"{where}: {cell(int(low[0]), int(low[1]))}; {rule} — {REBUILD}")
    marked = set(forbidden)
    if float(energy.max()) > 0.0:
        for i, j in zip(*np.nonzero(energy > 0.0), strict=True):
            if energy[i, j] != FORBIDDEN_ENERGY or (int(i), int(j)) not in marked:
                raise BundleError(f"{where}: {cell(int(i), int(j))}; {rule} — {REBUILD}")
    for i, j in marked:
        if energy[i, j] != FORBIDDEN_ENERGY:
            raise BundleError(f"{where}: {cell(i, j)}, but graph.json marks the pair \"never pick\" "
                              f"({FORBIDDEN_ENERGY:+g}); the two are not of one build — {REBUILD}")


def _check_embedding_index(folder: Path, manifest: Manifest, blob: bytes) -> None:
    """The rows' names and encoder that craftc records in the tensors' metadata (``index``), if
    any, must be the manifest's: a manifest whose objects were reordered or whose encoder was
    renamed after the build would otherwise pair every row with another name, silently."""
    where = folder / EMBEDDINGS_FILE
    try:
        size = int.from_bytes(blob[:8], "little")
        meta = json.loads(blob[8:8 + size]).get("__metadata__") or {}
        index = json.loads(meta["index"]) if "index" in meta else None
        if index is not None and not isinstance(index, dict):
            raise ValueError("not a JSON object")
    except (ValueError, TypeError, AttributeError, RecursionError) as exc:
        raise BundleError(f"{where}: its metadata 'index' does not parse ({exc}); {REBUILD}") from None
    if not index:
        return  # written by another tool: nothing recorded to compare
    expected: dict[str, Any] = {"verbs": manifest.verbs, "objects": manifest.objects,
                                "properties": manifest.properties, "encoder": manifest.text_encoder.id,
                                "verb_template": manifest.text_encoder.verb_template}
    for key, want in expected.items():
        if key not in index or index[key] == want:
            continue
        got = index[key]
        if isinstance(want, list) and isinstance(got, list):
            i = next((i for i, (a, b) in enumerate(zip(got, want, strict=False)) if a != b), min(len(got), len(want)))
            detail = (f"row {i} of its {key} is {shown(str(got[i])) if i < len(got) else 'missing'}, "
                      f"the manifest's {key}[{i}] is {shown(want[i]) if i < len(want) else 'missing'}")
        else:
            detail = f"its {key} is {shown(str(got))}, the manifest's is {shown(str(want))}"
        raise BundleError(f"{where}: {detail}; the embeddings and the manifest are not of one "
                          f"build — {REBUILD}")
