"""Emit pass: write a bundle into a temporary sibling folder, then swap it into place.

A failed or interrupted build never leaves a half-written ``--out``: either the previous bundle
is still there, or the new one is complete.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

from craft_e.schemas.v1.bundle import (
    BUILD_INFO_FILE,
    MANIFEST_FILE,
    BuildInfo,
    FileDigest,
    Manifest,
)


def file_digest(data: bytes) -> FileDigest:
    return FileDigest(sha256=hashlib.sha256(data).hexdigest(), bytes=len(data))


def model_json(model: Manifest | BuildInfo) -> bytes:
    return (json.dumps(model.model_dump(mode="json"), indent=2, sort_keys=True) + "\n").encode()


def write_bundle(
    out: Path, files: dict[str, bytes], manifest: Manifest, build_info: BuildInfo
) -> None:
    """Write ``files`` + manifest + build info to ``out`` atomically (rename of a whole folder)."""
    out = out.resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        for name, data in files.items():
            (staging / name).write_bytes(data)
        (staging / MANIFEST_FILE).write_bytes(model_json(manifest))
        (staging / BUILD_INFO_FILE).write_bytes(model_json(build_info))
        for path in staging.iterdir():
            with path.open("rb") as handle:
                os.fsync(handle.fileno())
        if out.exists():
            retired = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
            retired.rmdir()
            os.replace(out, retired)
            try:
                os.replace(staging, out)
            except BaseException:
                # Put the previous bundle back: --out must never be left empty or half-swapped.
                os.replace(retired, out)
                raise
            shutil.rmtree(retired, ignore_errors=True)
        else:
            os.replace(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
