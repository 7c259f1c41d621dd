"""Loading a KB bundle on the robot: verify first, then use.

``load_bundle`` checks the manifest's schema version, every file's sha256 and size, the content
hash, and that the bundle's text encoder is the one this runtime embeds with; any mismatch is a
``BundleError`` naming the file and the fix. It imports neither the compiler, httpx nor rdflib.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import stat
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from pydantic import ValidationError

from craft_e.schemas.v1.bundle import (
    BUNDLE_FILES,
    MANIFEST_FILE,
    BundleReport,
    Manifest,
    content_hash,
    listed_files_ok,
)

FloatArray = npt.NDArray[np.float32]
SUPPORTED_SCHEMA_VERSIONS = (1,)
#: Ceilings checked *before* reading: a manifest is kilobytes, a bundle file megabytes. A link to
#: /dev/zero or a multi-GB file is refused by its size or type, never read until memory runs out.
MAX_MANIFEST_BYTES = 16 << 20
MAX_FILE_BYTES = 1 << 30


class BundleError(RuntimeError):
    """A bundle cannot be trusted or read; the message names the file and the fix."""


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
    """A verified bundle in memory. Arrays are indexed in manifest order."""

    path: Path
    manifest: Manifest
    graph: dict[str, Any]
    energy: FloatArray  # [V, O] E_aff
    embeddings: dict[str, FloatArray]  # verb [V,d], verb_query [V,d], object [O,d], property [P,d]
    report: BundleReport
    open_world: dict[str, Any] | None = None  # open_world.json (None: a bundle built before it)
    _out: dict[str, list[tuple[str, dict[str, Any]]]] = field(default_factory=dict, repr=False)

    @cached_property
    def verb_index(self) -> dict[str, int]:
        return {v: i for i, v in enumerate(self.manifest.verbs)}

    @cached_property
    def object_index(self) -> dict[str, int]:
        return {o: i for i, o in enumerate(self.manifest.objects)}

    def out_edges(self, node_id: str) -> list[tuple[str, dict[str, Any]]]:
        """Edges leaving ``node_id`` (built lazily from graph.json)."""
        if not self._out:
            for edge in self.graph["edges"]:
                self._out.setdefault(edge["source"], []).append((edge["target"], edge))
        return self._out.get(node_id, [])

    def paths(self, verb: str | None = None, obj: str | None = None) -> list[PathStep]:
        """Every verb -> property -> object path (optionally for one verb and/or object)."""
        result: list[PathStep] = []
        tau = self.manifest.energy.tau
        verbs = [verb] if verb is not None else self.manifest.verbs
        for v in verbs:
            for prop_id, vp in self.out_edges(f"verb:{v}"):
                for obj_id, po in self.out_edges(prop_id):
                    name = obj_id.split(":", 1)[1]
                    if (obj is None or name == obj) and po["weight"] >= tau:
                        result.append(
                            PathStep(
                                v,
                                prop_id.split(":", 1)[1],
                                name,
                                vp["weight"],
                                po["weight"],
                                tuple(vp["provenance"] + po["provenance"]),
                            )
                        )
        return result


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def read_regular_file(path: Path, cap: int, expected: int | None = None) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``cap`` (or exactly ``expected``)
    bytes; a FIFO, device, socket or oversized file is a ``BundleError`` before any read.

    ``O_NONBLOCK`` makes opening a FIFO return at once (a plain open would wait for a writer
    forever); the type and size come from ``fstat`` of the opened descriptor, so a file swapped
    between the check and the read cannot slip through.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except IsADirectoryError:
        raise BundleError(f"{path}: is a folder, not a bundle file; rebuild the bundle") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise BundleError(
                f"{path}: not a regular file (a device, FIFO or socket); a bundle holds only "
                "regular files — rebuild or re-install it"
            )
        if expected is not None and info.st_size != expected:
            raise BundleError(
                f"{path}: content does not match the manifest ({info.st_size} bytes, expected "
                f"{expected}); the file was modified or truncated — rebuild or re-install the bundle"
            )
        if info.st_size > cap:
            raise BundleError(
                f"{path}: {info.st_size} bytes, more than {cap}; not a bundle file — rebuild or "
                "re-install the bundle"
            )
        chunks: list[bytes] = []
        left = info.st_size
        with os.fdopen(os.dup(fd), "rb") as handle:
            while left > 0:
                chunk = handle.read(min(left, 1 << 20))
                if not chunk:
                    break
                chunks.append(chunk)
                left -= len(chunk)
        return b"".join(chunks)
    finally:
        os.close(fd)


def read_manifest(folder: Path) -> Manifest:
    path = folder / MANIFEST_FILE
    if not folder.is_dir():
        raise BundleError(f"{folder}: not a bundle folder (build one with `craftc build`)")
    try:
        raw = json.loads(read_regular_file(path, MAX_MANIFEST_BYTES))
    except FileNotFoundError:
        raise BundleError(f"{path}: missing; this folder is not a CRAFT-E bundle") from None
    except PermissionError:
        raise BundleError(f"{path}: not readable by this user; fix the bundle's permissions") from None
    except (ValueError, RecursionError) as exc:
        raise BundleError(f"{path}: not valid JSON ({exc}); rebuild the bundle") from None
    version = raw.get("schema_version") if isinstance(raw, dict) else None
    if version not in SUPPORTED_SCHEMA_VERSIONS:
        raise BundleError(
            f"{path}: schema_version {version!r} is not supported by this runtime "
            f"(supports {SUPPORTED_SCHEMA_VERSIONS}); rebuild with a matching craftc"
        )
    try:
        return Manifest.model_validate(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise BundleError(f"{path}: {'.'.join(map(str, first['loc']))}: {first['msg']}") from None


def verify_files(folder: Path, manifest: Manifest) -> dict[str, bytes]:
    """Read every listed file and check its size and sha256, and the content hash."""
    if not listed_files_ok(set(manifest.files)):
        raise BundleError(
            f"{folder / MANIFEST_FILE}: lists {sorted(manifest.files)}, expected {sorted(BUNDLE_FILES)}"
        )
    data: dict[str, bytes] = {}
    for name, digest in sorted(manifest.files.items()):
        path = folder / name
        if digest.bytes > MAX_FILE_BYTES:
            raise BundleError(
                f"{folder / MANIFEST_FILE}: {name} is declared as {digest.bytes} bytes, more than "
                f"a bundle file may be ({MAX_FILE_BYTES}); rebuild the bundle"
            )
        try:
            blob = read_regular_file(path, MAX_FILE_BYTES, expected=digest.bytes)
        except FileNotFoundError:
            raise BundleError(
                f"{path}: missing from the bundle; rebuild or re-install it"
            ) from None
        except PermissionError:
            raise BundleError(f"{path}: not readable by this user; fix the bundle's permissions") from None
        if len(blob) != digest.bytes or _sha256(blob) != digest.sha256:
            raise BundleError(
                f"{path}: content does not match the manifest (sha256 {_sha256(blob)[:16]}..., "
                f"expected {digest.sha256[:16]}...); the file was modified or truncated — rebuild "
                "or re-install the bundle"
            )
        data[name] = blob
    if content_hash(manifest) != manifest.content_sha256:
        raise BundleError(
            f"{folder / MANIFEST_FILE}: content_sha256 does not match the manifest (a field was "
            "edited after the build); rebuild or re-install the bundle"
        )
    return data


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
    of ``trusted_keys`` (see ``runtime/package.py``), verified and unpacked privately first.
    """
    from safetensors.numpy import load as load_safetensors

    from craft_e.runtime.encoders.text import MINILM_ID, MINILM_SHA256

    folder = Path(path)
    if folder.is_file():
        from craft_e.runtime.package import load_packed_bundle

        return load_packed_bundle(
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
        graph = json.loads(data["graph.json"])
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
    check_content(folder, manifest, graph, energy, embeddings)
    if open_world is not None and not isinstance(open_world, dict):
        raise BundleError(f"{folder / 'open_world.json'}: not a JSON object; rebuild the bundle")
    return Bundle(folder, manifest, graph, energy.astype(np.float32), embeddings, report, open_world)


def check_content(
    folder: Path,
    manifest: Manifest,
    graph: Any,
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
    problem = _graph_problem(graph)
    if problem is not None:
        raise BundleError(f"{folder / 'graph.json'}: {problem}; rebuild the bundle")


def _graph_problem(graph: Any) -> str | None:
    """What is wrong with a node-link graph, or None (the shape ``Bundle.paths`` walks)."""
    if not isinstance(graph, dict):
        return "not a JSON object"
    nodes, edges = graph.get("nodes"), graph.get("edges")
    if not isinstance(nodes, list) or not isinstance(edges, list):
        return "needs 'nodes' and 'edges' lists"
    for i, node in enumerate(nodes):
        if not isinstance(node, dict) or not isinstance(node.get("id"), str) or ":" not in node["id"]:
            return f"node {i} has no '<kind>:<name>' id"
    for i, edge in enumerate(edges):
        if not isinstance(edge, dict):
            return f"edge {i} is not an object"
        source, target = edge.get("source"), edge.get("target")
        if not isinstance(source, str) or not isinstance(target, str):
            return f"edge {i} has no source/target ids"
        if ":" not in source or ":" not in target:
            return f"edge {i} ({source} -> {target}) has an id that is not '<kind>:<name>'"
        weight = edge.get("weight")
        if isinstance(weight, bool) or not isinstance(weight, int | float) or not math.isfinite(weight):
            return f"edge {i} ({edge['source']} -> {edge['target']}) has weight {weight!r}, not a finite number"
        provenance = edge.get("provenance")
        if not isinstance(provenance, list) or not all(isinstance(p, str) for p in provenance):
            return f"edge {i} ({edge['source']} -> {edge['target']}) has no list of record ids"
    return None
