"""Locating the read-only shared assets and the object catalog.

Every asset path in the simulator goes through here so a missing ``shared/`` folder fails once,
early, with a message that names the path and the fix (set ``CRAFT_SHARED``), instead of a
pybullet "cannot load URDF" deep inside a scene build.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from ...paths import shared_dir

CATALOG_FILE = Path(__file__).with_name("objects.json")


class SharedAssetsMissingError(FileNotFoundError):
    """A file the simulator needs is not under the shared folder."""


def shared_path(relative: str | Path) -> Path:
    """Absolute path of ``relative`` inside the shared folder; raises if it does not exist."""
    root = shared_dir()
    path = root / relative
    if not path.exists():
        raise SharedAssetsMissingError(
            f"shared asset not found: {path} (shared folder = {root}). "
            "Point CRAFT_SHARED at the shared/ folder that holds assets/robots and assets/objects."
        )
    return path


@dataclass(frozen=True)
class ObjectAsset:
    """One catalog entry: a simulator asset and the plain noun the grounding vocabulary uses."""

    asset_id: str
    name: str
    source: str
    urdf: str  # relative to the shared folder
    scale: float = 1.0

    @property
    def urdf_path(self) -> Path:
        return shared_path(self.urdf)


@cache
def object_catalog() -> dict[str, ObjectAsset]:
    """The catalog in ``objects.json``, keyed by asset id (loaded once per process)."""
    raw = json.loads(CATALOG_FILE.read_text(encoding="utf-8"))
    assets = [ObjectAsset(**entry) for entry in raw["objects"]]
    return {a.asset_id: a for a in assets}


def object_asset(asset_id: str) -> ObjectAsset:
    """Catalog entry for ``asset_id``; the error lists what exists so a typo is easy to fix."""
    catalog = object_catalog()
    if asset_id not in catalog:
        raise KeyError(
            f"unknown sim object {asset_id!r} (not in {CATALOG_FILE}); "
            f"known: {', '.join(sorted(catalog))}"
        )
    return catalog[asset_id]
