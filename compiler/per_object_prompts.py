"""Prompts asked once per object in its glossed sense (perception knowledge: size, colour).

The gloss is part of the rendered prompt, hence of the record key. A build looks these records up
and never asks for missing ones; ``craftc curate pending`` lists the prompts still to answer.
"""

from __future__ import annotations

from .llm_knowledge import NO_GLOSS
from .prompts import load_prompt
from .sources.llm import LLMSource, PromptCall


def object_call(prompt_id: str, obj: str, gloss: str = "") -> PromptCall:
    """The ``prompt_id`` prompt (its default version) for ``obj`` read in the sense of ``gloss``."""
    return PromptCall(load_prompt(prompt_id), obj, {"object": obj, "gloss": gloss or NO_GLOSS})


def pending_object_calls(prompt_id: str, source: LLMSource, objects: list[str],
                         glosses: dict[str, str]) -> dict[str, PromptCall]:
    """``prompt_id`` prompts of ``objects`` that no record answers yet, by object name."""
    calls = {o: object_call(prompt_id, o, glosses.get(o, "")) for o in objects}
    return {o: c for o, c in calls.items() if source.lookup(c) is None}
