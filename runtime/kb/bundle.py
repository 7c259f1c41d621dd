"""Loading a KB bundle on the robot: verify first, then use.

``load_bundle`` checks the manifest's schema version, every file's sha256 and size, the content
hash, that the bundle's text encoder is the one this runtime embeds with, and that the files
agree with each other and the manifest (``content.py``); any mismatch is a ``BundleError``
naming the file and the fix. It imports neither the compiler, httpx nor rdflib.
"""

from __future__ import annotations

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
from ...schemas.v1.graph_wire import GraphWire, graph_wire_problem
from .colours import TypicalColours
from .content import check_content, read_content
from .graph_index import GraphIndex
from .lookalikes import Lookalikes
from .sizes import TypicalSize
from .verify import (
    MAX_FILE_BYTES,
    MAX_MANIFEST_BYTES,
    SUPPORTED_SCHEMA_VERSIONS,
    BundleError,
    read_manifest,
    read_regular_file,
    verify_digests,
    verify_files,
)

# Re-exported: callers that load bundles need the verification helpers under one name.
__all__ = ["MAX_FILE_BYTES", "MAX_MANIFEST_BYTES", "SUPPORTED_SCHEMA_VERSIONS", "Bundle", "BundleError",
           "PathStep", "bundle_from_files", "check_content", "load_bundle", "parse_graph", "read_manifest", "read_regular_file",
           "verify_digests", "verify_files"]

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
    Every file is then parsed once and checked against the others (``content.read_content``,
    the checks ``craftc pack`` and ``craft install`` run too).
    """
    from ..encoders.text import MINILM_ID, MINILM_SHA256

    folder = Path(path)
    if folder.is_file():
        return _load_packed(
            folder, trusted_keys, check_encoder=check_encoder, encoder_id=encoder_id
        )
    manifest = read_manifest(folder)
    data = verify_digests(folder, manifest)
    want: str | None = None
    if check_encoder:
        want = encoder_id or MINILM_ID
        enc = manifest.text_encoder
        if enc.id != want or (want == MINILM_ID and enc.weights_sha256 != MINILM_SHA256):
            raise BundleError(
                f"{folder / MANIFEST_FILE}: built with text encoder {enc.id} "
                f"(weights {enc.weights_sha256[:12]}), this runtime uses {want}; rebuild the "
                "bundle with the runtime's encoder"
            )
    # the caller's own encoder (``encoder_id``), which it just matched, counts as a known space
    return bundle_from_files(folder, manifest, data, text_space=want)


def bundle_from_files(folder: Path, manifest: Manifest, data: dict[str, bytes], *,
                      text_space: str | None = None) -> Bundle:
    """The bundle these verified bytes hold (``verify_digests``'s), parsed once and checked
    against each other (``content.read_content``). ``craftc pack`` calls it on the very bytes it
    signs, so that its checks of derived files read those bytes, not a second read of the folder."""
    content = read_content(folder, manifest, data, text_space=text_space)
    return Bundle(folder, manifest, content.graph, content.energy.astype(np.float32, copy=False),
                  content.embeddings, content.report, content.open_world, content.sizes,
                  content.colours, content.lookalikes)


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
        raise PackageError(f"{path}: is a packed bundle (.craft), and no trusted keys were given to "
                           "verify its signer; pass the signer's craft-signing.pub with --trusted-key "
                           "(craftc validate/diff/explain/review/diagnose, craft ground/serve) or trusted_keys=[...] "
                           "(Python), or `craft install --trusted-key KEY` it and give the installed "
                           "folder")
    with unpacked(path, trusted_keys) as (folder, _):
        try:
            bundle = load_bundle(folder, check_encoder=check_encoder, encoder_id=encoder_id)
        except BundleError as exc:
            raise BundleError(str(exc).replace(str(folder), str(path))) from None
    bundle.path = path
    return bundle
