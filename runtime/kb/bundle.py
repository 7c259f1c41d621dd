"""Loading a KB bundle on the robot: verify first, then use.

``load_bundle`` checks the manifest's schema version, every file's sha256 and size, the content
hash, and that the bundle's text encoder is the one this runtime embeds with; any mismatch is a
``BundleError`` naming the file and the fix. It imports neither the compiler, httpx nor rdflib.
"""

from __future__ import annotations

import io
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from pydantic import ValidationError

from ...schemas.v1.bundle import (
    MANIFEST_FILE,
    BundleReport,
    Manifest,
)
from ...schemas.v1.graph import KnowledgeGraph
from ...schemas.v1.graph_wire import GraphWire, graph_wire_problem, validate_graph_json
from ..encoders.conse import imagenet_class_index
from .colours import COLOURS_FILE, TypicalColours, parse_colours
from .graph_index import GraphIndex
from .lookalikes import LOOKALIKES_FILE, Lookalikes, parse_lookalikes
from .sizes import SIZES_FILE, SizesError, TypicalSize, parse_sizes
from .verify import (
    MAX_FILE_BYTES,
    MAX_MANIFEST_BYTES,
    SUPPORTED_SCHEMA_VERSIONS,
    BundleError,
    read_manifest,
    read_regular_file,
    verify_files,
)

# Re-exported: callers that load bundles need the verification helpers under one name.
__all__ = ["MAX_FILE_BYTES", "MAX_MANIFEST_BYTES", "SUPPORTED_SCHEMA_VERSIONS", "Bundle", "BundleError",
           "PathStep", "check_content", "load_bundle", "parse_graph", "read_manifest", "read_regular_file",
           "verify_files"]

FloatArray = npt.NDArray[np.float32]
@dataclass(frozen=True)
class PathStep:
    """One explanation path verb -> property -> object with weights and record ids."""

    verb: str
    prop: str
    obj: str
    w_vp: float
    w_po: float
    provenance: tuple[str, ...]


@dataclass
class Bundle:
    """A verified bundle in memory. Arrays are indexed in manifest order.

    ``graph_data`` is ``graph.json`` as checked at load (plain data, every constraint of
    :class:`KnowledgeGraph` already met); ``graph`` makes the models of it the first time it is
    asked for (``schemas/v1/graph_wire.py``: at 150,000 edges that is a second, which loading
    no longer spends), and ``index`` the lookups grounding needs, without models."""

    path: Path
    manifest: Manifest
    graph_data: GraphWire = field(repr=False)
    energy: FloatArray  # [V, O] E_aff
    embeddings: dict[str, FloatArray]  # verb [V,d], verb_query [V,d], object [O,d], property [P,d]
    report: BundleReport
    open_world: dict[str, Any] | None = None  # open_world.json (None: a bundle built before it)
    #: object_sizes.json: typical sizes by object name (empty: none recorded, or an older bundle)
    sizes: dict[str, TypicalSize] = field(default_factory=dict)
    #: object_colours.json: typical colours by object name (empty: none recorded, or an older bundle)
    colours: dict[str, TypicalColours] = field(default_factory=dict)
    #: object_lookalikes.json: ImageNet classes photos of each object get (empty: none recorded,
    #: or an older bundle)
    lookalikes: dict[str, Lookalikes] = field(default_factory=dict)

    @cached_property
    def graph(self) -> KnowledgeGraph:
        """The verb -> property -> object graph as models (built once, from ``graph_data``)."""
        return parse_graph(self.path, self.graph_data)

    @cached_property
    def index(self) -> GraphIndex:
        """What grounding reads of the graph, without its models (``graph_index.py``)."""
        return GraphIndex.from_wire(self.graph_data)

    @cached_property
    def verb_index(self) -> dict[str, int]:
        return {v: i for i, v in enumerate(self.manifest.verbs)}

    @cached_property
    def object_index(self) -> dict[str, int]:
        return {o: i for i, o in enumerate(self.manifest.objects)}

    def paths(self, verb: str | None = None, obj: str | None = None) -> list[PathStep]:
        """Every verb -> property -> object path with ``w_po >= tau`` (optionally for one verb
        and/or object)."""
        result: list[PathStep] = []
        tau = self.manifest.energy.tau
        g = self.index
        for v in [verb] if verb is not None else self.manifest.verbs:
            for vp in g.verb_properties.get(v, []):
                for po in g.property_objects.get(vp.target_name, []):
                    if (obj is None or po.target_name == obj) and po.weight >= tau:
                        result.append(PathStep(v, vp.target_name, po.target_name, vp.weight, po.weight,
                                               tuple(vp.provenance + po.provenance)))
        return result


def load_bundle(
    path: Path | str,
    *,
    check_encoder: bool = True,
    encoder_id: str | None = None,
    trusted_keys: Sequence[bytes | str] | None = None,
) -> Bundle:
    """Verify and load a bundle folder, or a signed ``.craft`` file.

    With ``check_encoder`` the bundle's text encoder must be the runtime's (``encoder_id``,
    default minilm-l6-v2 with its pinned weights hash): embeddings from another space would
    silently produce wrong cosines. A file is a packed bundle: it is used only if signed by one
    of ``trusted_keys`` (see ``runtime/kb/package.py``), verified and unpacked privately first.
    """
    from safetensors.numpy import load as load_safetensors

    from ..encoders.text import MINILM_ID, MINILM_SHA256

    folder = Path(path)
    if folder.is_file():
        return _load_packed(
            folder, trusted_keys, check_encoder=check_encoder, encoder_id=encoder_id
        )
    manifest = read_manifest(folder)
    data = verify_files(folder, manifest)
    if check_encoder:
        want = encoder_id or MINILM_ID
        enc = manifest.text_encoder
        if enc.id != want or (want == MINILM_ID and enc.weights_sha256 != MINILM_SHA256):
            raise BundleError(
                f"{folder / MANIFEST_FILE}: built with text encoder {enc.id} "
                f"(weights {enc.weights_sha256[:12]}), this runtime uses {want}; rebuild the "
                "bundle with the runtime's encoder"
            )
    try:
        graph_data = validate_graph_json(data["graph.json"])
    except ValidationError as exc:  # malformed JSON, or a constraint of the graph broken
        raise BundleError(f"{folder / 'graph.json'}: {graph_wire_problem(exc)}; rebuild the bundle") from None
    try:
        energy = np.load(io.BytesIO(data["affordance_energy.npy"]), allow_pickle=False)
        embeddings = {
            k: np.asarray(v, dtype=np.float32)
            for k, v in load_safetensors(data["embeddings.safetensors"]).items()
        }
        report = BundleReport.model_validate_json(data["report.json"])
        open_world = json.loads(data["open_world.json"]) if "open_world.json" in data else None
    except (ValueError, ValidationError, KeyError, RecursionError) as exc:
        raise BundleError(
            f"{folder}: a bundle file does not parse ({exc}); rebuild the bundle"
        ) from None
    check_content(folder, manifest, energy, embeddings)
    if open_world is not None and not isinstance(open_world, dict):
        raise BundleError(f"{folder / 'open_world.json'}: not a JSON object; rebuild the bundle")
    try:
        sizes = parse_sizes(folder, data[SIZES_FILE], manifest.objects) if SIZES_FILE in data else {}
        colours = (parse_colours(folder, data[COLOURS_FILE], manifest.objects)
                   if COLOURS_FILE in data else {})
        lookalikes = (parse_lookalikes(folder, data[LOOKALIKES_FILE], manifest.objects,
                                       imagenet_class_index().keys())
                      if LOOKALIKES_FILE in data else {})
    except SizesError as exc:  # ColoursError and LookalikesError are ones
        raise BundleError(str(exc)) from None
    return Bundle(folder, manifest, graph_data, energy.astype(np.float32, copy=False), embeddings, report, open_world,
                  sizes, colours, lookalikes)


def check_content(
    folder: Path,
    manifest: Manifest,
    energy: npt.NDArray[Any],
    embeddings: dict[str, FloatArray],
) -> None:
    """Values and shapes a grounder relies on; consistent hashes do not make content sane.

    A bundle written by a buggy or hostile tool can hash consistently and still hold NaN, a
    tensor of another width than the text encoder's, or a graph whose weights are strings:
    the grounder would then crash mid-request or rank by NaN. Each is refused here, naming
    the file and the fault.
    """
    v, o = len(manifest.verbs), len(manifest.objects)
    if energy.shape != (v, o):
        raise BundleError(
            f"{folder / 'affordance_energy.npy'}: shape {energy.shape}, manifest says ({v}, {o})"
        )
    if energy.dtype.kind != "f" or not np.isfinite(energy).all():
        raise BundleError(
            f"{folder / 'affordance_energy.npy'}: holds NaN, infinite or non-float values; "
            "rebuild the bundle"
        )
    dim = manifest.text_encoder.dim
    for key, rows in (
        ("verb", v),
        ("verb_query", v),
        ("object", o),
        ("property", len(manifest.properties)),
    ):
        if key not in embeddings or embeddings[key].ndim != 2 or embeddings[key].shape[0] != rows:
            raise BundleError(
                f"{folder / 'embeddings.safetensors'}: tensor {key!r} missing or not {rows} rows"
            )
        if embeddings[key].shape[1] != dim:
            raise BundleError(
                f"{folder / 'embeddings.safetensors'}: tensor {key!r} is {embeddings[key].shape[1]} "
                f"wide, the manifest's text encoder embeds into {dim}; rebuild the bundle"
            )
        if not np.isfinite(embeddings[key]).all():
            raise BundleError(
                f"{folder / 'embeddings.safetensors'}: tensor {key!r} holds NaN or infinite "
                "values; rebuild the bundle"
            )


def parse_graph(folder: Path, raw: Any) -> KnowledgeGraph:
    """``graph.json`` as a :class:`KnowledgeGraph`, or a ``BundleError`` naming the first fault
    (a weight that is a string, a missing list, an id that is not ``<kind>:<name>``)."""
    try:
        return KnowledgeGraph.model_validate(raw)
    except ValidationError as exc:  # the same words as the check at load (``graph_wire_problem``)
        raise BundleError(f"{folder / 'graph.json'}: {graph_wire_problem(exc)}; rebuild the bundle") from None


def _load_packed(
    path: Path,
    trusted_keys: Sequence[bytes | str] | None,
    *,
    check_encoder: bool = True,
    encoder_id: str | None = None,
) -> Bundle:
    """``load_bundle`` for a ``.craft`` file: verify, unpack privately, load, clean up.

    The bundle is read fully into memory by ``load_bundle``, so the temporary folder can go;
    ``Bundle.path`` names the package so messages and logs point at what the user passed.
    """
    from .package import PACKAGE_MAGIC, PackageError, unpacked

    try:
        with path.open("rb") as handle:  # a regular file (load_bundle checked): never blocks
            head = handle.read(len(PACKAGE_MAGIC))
    except OSError as exc:
        raise BundleError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if head != PACKAGE_MAGIC:
        raise BundleError(f"{path}: is a file, neither a bundle folder nor a packed bundle (.craft); "
                          "give the bundle's folder (the one holding manifest.json) or a .craft file")
    if trusted_keys is None:
        raise PackageError(f"{path}: is a packed bundle, and no trusted keys were given; pass "
                           "trusted_keys=[<craft-signing.pub>] (or --trusted-key) to verify its signer")
    with unpacked(path, trusted_keys) as (folder, _):
        try:
            bundle = load_bundle(folder, check_encoder=check_encoder, encoder_id=encoder_id)
        except BundleError as exc:
            raise BundleError(str(exc).replace(str(folder), str(path))) from None
    bundle.path = path
    return bundle
