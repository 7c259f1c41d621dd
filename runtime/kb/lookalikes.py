"""``object_lookalikes.json``: a bundle's look-alike ImageNet classes, checked before the runtime uses them.

The compiler writes one entry per object that an ``object_lookalike`` record answers: up to five
ImageNet-1k class names with the share of photos of a typical instance expected to get each. The
runtime's look-alike cue weighs an ROI's classes against them (``grounding/lookalike_cue.py``); a
malformed entry would silently skew ``p(o | r)``, so each is refused here naming the file, the
object and the fault.
"""

from __future__ import annotations

import math
from collections.abc import Set
from pathlib import Path

from .sizes import SizesError, object_entries

LOOKALIKES_FILE = "object_lookalikes.json"
#: One object's look-alikes: (ImageNet-1k class name, expected share of photos), as answered.
Lookalikes = tuple[tuple[str, float], ...]


class LookalikesError(SizesError):
    """``object_lookalikes.json`` does not parse or holds an impossible entry."""


def parse_lookalikes(folder: Path, blob: bytes, objects: list[str],
                     class_names: Set[str] | None = None) -> dict[str, Lookalikes]:
    """The look-alikes in ``blob`` by object name; every name must be one of the bundle's
    ``objects`` and, when ``class_names`` is given, every class one of them."""
    where = folder / LOOKALIKES_FILE
    entries = object_entries(where, blob, objects, LookalikesError)
    out: dict[str, Lookalikes] = {}
    for name, entry in entries.items():
        try:
            shares = {str(k): float(v) for k, v in dict(entry["classes"]).items()}
        except (KeyError, TypeError, ValueError):
            raise LookalikesError(f"{where}: {name!r} needs 'classes' (ImageNet class -> share); "
                                  "rebuild the bundle") from None
        if not 1 <= len(shares) <= 5:
            raise LookalikesError(f"{where}: {name!r} names {len(shares)} classes; one to five are "
                                  "expected; rebuild the bundle")
        if not all(math.isfinite(v) and 0 < v <= 1 for v in shares.values()) or sum(shares.values()) > 1 + 1e-6:
            raise LookalikesError(f"{where}: {name!r} has shares {shares}; each in (0, 1], adding up to "
                                  "1 or less, are expected; rebuild the bundle")
        unknown = sorted(set(shares) - class_names) if class_names is not None else []
        if unknown:
            raise LookalikesError(f"{where}: {name!r} names {unknown}, not ImageNet-1k classes of the "
                                  "image encoder; rebuild the bundle")
        out[name] = tuple(sorted(shares.items()))
    return out
