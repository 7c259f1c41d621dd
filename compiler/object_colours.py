"""Perception knowledge: the colours a typical instance of each object shows (prompt ``object_colour``).

The image encoder names rendered objects from the ImageNet label space; where that space has no
good word it lands on a name of the wrong colour (a peach called a "racquetball"). One record per
object, in the object's glossed sense, gives up to three basic colour terms with the share of the
visible surface each covers, and how much instances vary; the runtime's colour cue
(``runtime/grounding/colour_cue.py``) compares them with the colours of an ROI's pixels. A build
looks the records up and never asks for missing ones: the cue is off for a vocabulary that is not
fully covered.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from ..schemas.v1.payloads import ObjectColour
from .per_object_prompts import object_call, pending_object_calls
from .sources.llm import LLMSource, PromptCall

PROMPT_ID = "object_colour"


@dataclass(frozen=True)
class RecordedColours:
    """One object's answer: (colour term, share) pairs as answered, and how much it varies."""

    colours: tuple[tuple[str, float], ...]
    variability: str
    record_key: str

    def to_dict(self) -> dict[str, object]:
        return {"colours": {term: share for term, share in self.colours},
                "variability": self.variability, "record": self.record_key}


def colour_call(obj: str, gloss: str = "") -> PromptCall:
    """The ``object_colour@v1`` prompt for ``obj`` read in the sense of ``gloss``."""
    return object_call(PROMPT_ID, obj, gloss)


def recorded_colours(source: LLMSource, objects: list[str],
                     glosses: dict[str, str]) -> dict[str, RecordedColours]:
    """The recorded colours of every object in ``objects`` that has them (missing ones left out)."""
    out: dict[str, RecordedColours] = {}
    for obj in objects:
        record = source.lookup(colour_call(obj, glosses.get(obj, "")))
        if record is None:
            continue
        answer = ObjectColour.model_validate(record.payload)
        out[obj] = RecordedColours(tuple((c.colour, float(c.share)) for c in answer.colours),
                                   answer.variability, record.key)
    return out


def pending_colour_calls(source: LLMSource, objects: list[str],
                         glosses: dict[str, str]) -> dict[str, PromptCall]:
    """Colour prompts of ``objects`` that no record answers yet, by object name."""
    return pending_object_calls(PROMPT_ID, source, objects, glosses)


def colours_json(colours: dict[str, RecordedColours], provider: str, model: str) -> bytes:
    """``object_colours.json``: every recorded answer, by object name (sorted, byte-stable)."""
    body = {"prompt": f"{PROMPT_ID}@v1", "provider": provider, "model": model,
            "objects": {name: colours[name].to_dict() for name in sorted(colours)}}
    return (json.dumps(body, indent=1, sort_keys=True) + "\n").encode()
