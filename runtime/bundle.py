"""Loading a KB bundle on the robot: verify first, then use.

``load_bundle`` checks the manifest's schema version, every file's sha256 and size, the content
hash, and that the bundle's text encoder is the one this runtime embeds with; any mismatch is a
``BundleError`` naming the file and the fix. It imports neither the compiler, httpx nor rdflib.
"""

from __future__ import annotations

import hashlib
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

from craft_e.schemas.v1.bundle import (
    BUNDLE_FILES,
    MANIFEST_FILE,
    BundleReport,
    Manifest,
    content_hash,
)

FloatArray = npt.NDArray[np.float32]
SUPPORTED_SCHEMA_VERSIONS = (1,)


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


def read_manifest(folder: Path) -> Manifest:
    path = folder / MANIFEST_FILE
    if not folder.is_dir():
        raise BundleError(f"{folder}: not a bundle folder (build one with `craftc build`)")
    try:
        raw = json.loads(path.read_bytes())
    except FileNotFoundError:
        raise BundleError(f"{path}: missing; this folder is not a CRAFT-E bundle") from None
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
    if set(manifest.files) != set(BUNDLE_FILES):
        raise BundleError(
            f"{folder / MANIFEST_FILE}: lists {sorted(manifest.files)}, expected {sorted(BUNDLE_FILES)}"
        )
    data: dict[str, bytes] = {}
    for name, digest in sorted(manifest.files.items()):
        path = folder / name
        try:
            blob = path.read_bytes()
        except FileNotFoundError:
            raise BundleError(
                f"{path}: missing from the bundle; rebuild or re-install it"
            ) from None
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
    except (ValueError, ValidationError, KeyError) as exc:
        raise BundleError(
            f"{folder}: a bundle file does not parse ({exc}); rebuild the bundle"
        ) from None
    v, o = len(manifest.verbs), len(manifest.objects)
    if energy.shape != (v, o):
        raise BundleError(
            f"{folder / 'affordance_energy.npy'}: shape {energy.shape}, manifest says ({v}, {o})"
        )
    for key, rows in (
        ("verb", v),
        ("verb_query", v),
        ("object", o),
        ("property", len(manifest.properties)),
    ):
        if key not in embeddings or embeddings[key].shape[0] != rows:
            raise BundleError(
                f"{folder / 'embeddings.safetensors'}: tensor {key!r} missing or not {rows} rows"
            )
    return Bundle(folder, manifest, graph, energy.astype(np.float32), embeddings, report)
