"""``object_colours.json``: a bundle's typical object colours, checked before the runtime uses them.

The compiler writes one entry per object that an ``object_colour`` record answers: up to three of
the eleven basic colour terms with the share of the visible surface each covers, and how much
instances vary. The runtime's colour cue compares them with the colours of an ROI's pixels; a
malformed entry would silently skew ``p(o | r)``, so each is refused here naming the file, the
object and the fault.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from .sizes import VARIABILITIES, SizesError, object_entries

COLOURS_FILE = "object_colours.json"
#: The basic colour terms, in the order of the runtime's colour histograms (``perception/colours.py``).
COLOUR_TERMS: tuple[str, ...] = ("black", "white", "grey", "red", "orange", "yellow", "green", "blue",
                                 "purple", "pink", "brown")


class ColoursError(SizesError):
    """``object_colours.json`` does not parse or holds an impossible entry."""


@dataclass(frozen=True)
class TypicalColours:
    """The shares of a typical instance's visible surface by colour term, and how much it varies."""

    shares: tuple[tuple[str, float], ...]
    variability: str


def parse_colours(folder: Path, blob: bytes, objects: list[str]) -> dict[str, TypicalColours]:
    """The colours in ``blob`` by object name; every name must be one of the bundle's ``objects``."""
    where = folder / COLOURS_FILE
    out: dict[str, TypicalColours] = {}
    for name, entry in object_entries(where, blob, objects, ColoursError).items():
        try:
            shares = {str(k): float(v) for k, v in dict(entry["colours"]).items()}
            variability = str(entry["variability"])
        except (KeyError, TypeError, ValueError):
            raise ColoursError(f"{where}: {name!r} needs 'colours' (colour term -> share) and "
                               "'variability'; rebuild the bundle") from None
        unknown = sorted(set(shares) - set(COLOUR_TERMS))
        if unknown or not shares:
            raise ColoursError(f"{where}: {name!r} has colours {sorted(shares)}; one to three of "
                               f"{', '.join(COLOUR_TERMS)} are expected; rebuild the bundle")
        if not all(math.isfinite(v) and 0 < v <= 1 for v in shares.values()) or sum(shares.values()) > 1 + 1e-6:
            raise ColoursError(f"{where}: {name!r} has shares {shares}; each in (0, 1], adding up to "
                               "1 or less, are expected; rebuild the bundle")
        if variability not in VARIABILITIES:
            raise ColoursError(f"{where}: {name!r} has variability {variability!r}, not one of "
                               f"{', '.join(VARIABILITIES)}; rebuild the bundle")
        out[name] = TypicalColours(tuple(sorted(shares.items())), variability)
    return out
