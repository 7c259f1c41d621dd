"""Perception knowledge: the ImageNet-1k classes photos of each object get (prompt ``object_lookalike``).

The robot's image recogniser only knows the ImageNet-1k label space, and ConSE maps its answer to
a vocabulary name by *text* similarity: a look-alike class whose name means something else lands
on the wrong name. One record per object, in the object's glossed sense, names up to five classes
with the share of photos expected to get each; the runtime's look-alike cue weighs an ROI's
classes against them (``runtime/grounding/lookalike_cue.py``). A build looks the records up and
never asks for missing ones: the cue is off for a vocabulary that is not fully covered.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from ..schemas.v1.payloads import ObjectLookalikes
from .per_object_prompts import LOOKALIKE_PROMPT_ID as PROMPT_ID
from .per_object_prompts import object_call
from .sources.llm import LLMSource

__all__ = ["PROMPT_ID", "RecordedLookalikes", "lookalikes_json", "recorded_lookalikes"]


@dataclass(frozen=True)
class RecordedLookalikes:
    """One object's answer: (ImageNet class, share) pairs as answered, and the record it came from."""

    classes: tuple[tuple[str, float], ...]
    record_key: str

    def to_dict(self) -> dict[str, object]:
        return {"classes": dict(self.classes), "record": self.record_key}


def recorded_lookalikes(source: LLMSource, objects: list[str],
                        glosses: dict[str, str]) -> dict[str, RecordedLookalikes]:
    """The recorded look-alike classes of every object in ``objects`` that has them."""
    out: dict[str, RecordedLookalikes] = {}
    for obj in objects:
        record = source.lookup(object_call(PROMPT_ID, obj, glosses.get(obj, "")))
        if record is None:
            continue
        answer = ObjectLookalikes.model_validate(record.payload)
        out[obj] = RecordedLookalikes(tuple((c.imagenet_class, float(c.share)) for c in answer.classes),
                                      record.key)
    return out


def lookalikes_json(lookalikes: dict[str, RecordedLookalikes], provider: str, model: str) -> bytes:
    """``object_lookalikes.json``: every recorded answer, by object name (sorted, byte-stable)."""
    body = {"prompt": f"{PROMPT_ID}@v1", "provider": provider, "model": model,
            "objects": {name: lookalikes[name].to_dict() for name in sorted(lookalikes)}}
    return (json.dumps(body, indent=1, sort_keys=True) + "\n").encode()
