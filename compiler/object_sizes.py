"""Perception knowledge: the typical physical size of each object (prompt ``object_size``).

A depth camera measures an ROI's extents in metres; knowing that a typical apple is about
8 x 8 x 7 cm and a hammer 33 x 13 x 4 cm tells the runtime which names an ROI can carry, with no
picture of either. One record per object, asked in the object's glossed sense (the gloss is part
of the rendered prompt, hence of the record key). A build looks the records up and never asks for
missing ones: an object without a record simply has no size, and the runtime's size cue is off
for a vocabulary that is not fully covered.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from ..schemas.v1.payloads import ObjectSize
from .per_object_prompts import object_call, pending_object_calls
from .sources.llm import LLMSource, PromptCall

PROMPT_ID = "object_size"


@dataclass(frozen=True)
class RecordedSize:
    """One object's answer: box edges in centimetres (longest first) and how much it varies."""

    dimensions_cm: tuple[float, float, float]
    variability: str
    record_key: str

    def to_dict(self) -> dict[str, object]:
        return {"dimensions_cm": list(self.dimensions_cm), "variability": self.variability,
                "record": self.record_key}


def size_call(obj: str, gloss: str = "") -> PromptCall:
    """The ``object_size@v1`` prompt for ``obj`` read in the sense of ``gloss``."""
    return object_call(PROMPT_ID, obj, gloss)


def recorded_sizes(source: LLMSource, objects: list[str], glosses: dict[str, str]) -> dict[str, RecordedSize]:
    """The recorded size of every object in ``objects`` that has one (missing ones are left out)."""
    out: dict[str, RecordedSize] = {}
    for obj in objects:
        record = source.lookup(size_call(obj, glosses.get(obj, "")))
        if record is None:
            continue
        answer = ObjectSize.model_validate(record.payload)
        a, b, c = (float(x) for x in answer.dimensions_cm)
        out[obj] = RecordedSize((a, b, c), answer.variability, record.key)
    return out


def pending_size_calls(source: LLMSource, objects: list[str], glosses: dict[str, str]) -> dict[str, PromptCall]:
    """Size prompts of ``objects`` that no record answers yet, by object name."""
    return pending_object_calls(PROMPT_ID, source, objects, glosses)


def sizes_json(sizes: dict[str, RecordedSize], provider: str, model: str) -> bytes:
    """``object_sizes.json``: every recorded size, by object name (sorted, byte-stable)."""
    body = {"prompt": f"{PROMPT_ID}@v1", "provider": provider, "model": model,
            "objects": {name: sizes[name].to_dict() for name in sorted(sizes)}}
    return (json.dumps(body, indent=1, sort_keys=True) + "\n").encode()
