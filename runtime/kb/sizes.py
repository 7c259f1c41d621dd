"""``object_sizes.json``: a bundle's typical object sizes, checked before the runtime uses them.

The compiler writes one entry per object that an ``object_size`` record answers (edges in
centimetres, longest first, and how much instances vary). The runtime's size cue compares them
with the extents a depth camera measures of an ROI; a malformed entry would silently skew
``p(o | r)``, so each is refused here naming the file, the object and the fault.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

SIZES_FILE = "object_sizes.json"
VARIABILITIES = ("low", "medium", "high")


class SizesError(ValueError):
    """``object_sizes.json`` does not parse or holds an impossible entry."""


@dataclass(frozen=True)
class TypicalSize:
    """A typical instance's bounding-box edges in metres (longest first) and its spread."""

    dimensions_m: tuple[float, float, float]
    variability: str


def object_entries(where: Path, blob: bytes, objects: list[str], error: type[SizesError]) -> dict[str, Any]:
    """A perception-knowledge file's ``"objects"`` table (sizes, colours), every name one of the
    bundle's ``objects``; ``error`` (naming ``where``) otherwise."""
    try:
        raw: Any = json.loads(blob)
        entries = raw["objects"]
        if not isinstance(entries, dict):
            raise TypeError("'objects' is not a JSON object")
    except (ValueError, KeyError, TypeError, RecursionError) as exc:
        raise error(f"{where}: does not parse ({exc}); rebuild the bundle") from None
    unknown = sorted(set(entries) - set(objects))
    if unknown:
        raise error(f"{where}: {unknown[0]!r} is not an object of the bundle; rebuild the bundle")
    return entries


def parse_sizes(folder: Path, blob: bytes, objects: list[str]) -> dict[str, TypicalSize]:
    """The sizes in ``blob`` by object name; every name must be one of the bundle's ``objects``."""
    where = folder / SIZES_FILE
    out: dict[str, TypicalSize] = {}
    for name, entry in object_entries(where, blob, objects, SizesError).items():
        try:
            dims = [float(x) for x in entry["dimensions_cm"]]
            variability = str(entry["variability"])
        except (KeyError, TypeError, ValueError):
            raise SizesError(f"{where}: {name!r} needs 'dimensions_cm' (3 numbers) and "
                             "'variability'; rebuild the bundle") from None
        if len(dims) != 3 or not all(math.isfinite(d) and d > 0 for d in dims) or dims != sorted(dims, reverse=True):
            raise SizesError(f"{where}: {name!r} has dimensions_cm {dims}; three positive numbers, "
                             "longest first, are expected; rebuild the bundle")
        if variability not in VARIABILITIES:
            raise SizesError(f"{where}: {name!r} has variability {variability!r}, not one of "
                             f"{', '.join(VARIABILITIES)}; rebuild the bundle")
        out[name] = TypicalSize((dims[0] / 100, dims[1] / 100, dims[2] / 100), variability)
    return out
