"""Prompts asked once per object in its glossed sense (perception knowledge: size, colour, look-alikes).

The gloss is part of the rendered prompt, hence of the record key. A build looks these records up
and never asks for missing ones; ``craftc curate pending`` lists the prompts still to answer.
"""

from __future__ import annotations

from .llm_knowledge import NO_GLOSS
from .prompts import load_prompt
from .sources.llm import LLMSource, PromptCall

#: The prompt that names the image classifier's label space (``object_lookalike``).
LOOKALIKE_PROMPT_ID = "object_lookalike"


def object_call(prompt_id: str, obj: str, gloss: str = "") -> PromptCall:
    """The ``prompt_id`` prompt (its default version) for ``obj`` read in the sense of ``gloss``.

    ``object_lookalike`` also lists the classifier's 1000 class names: an answer can only name
    classes the model it describes can output, so the list is part of the prompt (and its key).
    """
    variables: dict[str, object] = {"object": obj, "gloss": gloss or NO_GLOSS}
    if prompt_id == LOOKALIKE_PROMPT_ID:
        from ..runtime.encoders.conse import imagenet_class_names

        variables["classes"] = "; ".join(imagenet_class_names())
    return PromptCall(load_prompt(prompt_id), obj, variables)


def pending_object_calls(prompt_id: str, source: LLMSource, objects: list[str],
                         glosses: dict[str, str]) -> dict[str, PromptCall]:
    """``prompt_id`` prompts of ``objects`` that no record answers yet, by object name."""
    calls = {o: object_call(prompt_id, o, glosses.get(o, "")) for o in objects}
    return {o: c for o, c in calls.items() if source.lookup(c) is None}
