"""Prompt templates (``prompts/<id>.<version>.md``) and their rendering into chat messages.

The templates are package data of ``craft_e.prompts`` (the design card's top-level ``prompts/``),
found through ``importlib.resources``: an installed wheel carries them, no checkout needed.

A template has a ``## system`` and a ``## user`` section and ``str.format`` placeholders. The
prompt id and version come from the file name, and ``<id>@<version>`` is part of every record
key: editing a template means a new version file, which addresses new records.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel

from ..schemas.v1.payloads import (
    ObjectColour,
    ObjectLookalikes,
    ObjectProperties,
    ObjectSize,
    PropertyObjects,
    VerbObjects,
    VerbProperties,
    VerbPropertiesV2,
)
from ..schemas.v1.records import Message

#: The shipped templates (a plain folder: the package is installed unpacked, never zipped).
PROMPTS_DIR = Path(str(resources.files("craft_e.prompts")))

PAYLOADS: dict[str, type[BaseModel]] = {
    "verb_properties": VerbProperties,
    "object_properties": ObjectProperties,
    "verb_objects": VerbObjects,
    "property_objects": PropertyObjects,
    "object_size": ObjectSize,
    "object_colour": ObjectColour,
    "object_lookalike": ObjectLookalikes,
}
#: Payload models whose shape changed with a prompt version (``<id>@<version>``).
VERSIONED_PAYLOADS: dict[str, type[BaseModel]] = {
    "verb_properties@v2": VerbPropertiesV2,
    "verb_properties@v3": VerbPropertiesV2,  # v2 + the verb's sense; same answer shape
}
#: v2 asks for discriminating, defined properties and reads objects in a glossed sense
#: (issue 9); v1 stays loadable so its records keep replaying.
PROMPT_VERSIONS = ("v1", "v2")
PromptVersion = Literal["v1", "v2"]
DEFAULT_PROMPT_VERSION: PromptVersion = "v2"
DEFAULT_VERSIONS = {
    "verb_properties": DEFAULT_PROMPT_VERSION,
    "object_properties": DEFAULT_PROMPT_VERSION,
    "verb_objects": DEFAULT_PROMPT_VERSION,
    "property_objects": "v1",
    "object_size": "v1",
    "object_colour": "v1",
    "object_lookalike": "v1",
}
_SECTION = re.compile(r"^## (system|user)\s*$", re.MULTILINE)


class PromptError(ValueError):
    """A template is missing or malformed."""


@dataclass(frozen=True)
class PromptTemplate:
    prompt_id: str
    version: str
    system: str
    user: str
    path: Path

    @property
    def ref(self) -> str:
        """``<id>@<version>``: the name used in record keys and manifests."""
        return f"{self.prompt_id}@{self.version}"

    @property
    def payload_model(self) -> type[BaseModel]:
        return VERSIONED_PAYLOADS.get(self.ref, PAYLOADS[self.prompt_id])

    def response_schema(self) -> dict[str, Any]:
        """The payload's JSON Schema, a fresh copy per call (callers may keep or change it)."""
        schema: dict[str, Any] = json.loads(_schema_text(self.payload_model))
        return schema

    def render(self, **variables: Any) -> list[Message]:
        """Fill the placeholders; a missing variable is a template error, not a silent blank."""
        try:
            return [
                Message(role="system", content=self.system.format(**variables)),
                Message(role="user", content=self.user.format(**variables)),
            ]
        except KeyError as exc:
            raise PromptError(f"{self.path}: placeholder {exc} has no value") from exc


@cache
def _schema_text(model: type[BaseModel]) -> str:
    """``model``'s JSON Schema as text, made once per payload model: every request of a build
    carries it (and its key hashes it), and pydantic regenerating it per request was 40 % of a
    warm 1,000 x 10,000 rebuild (``benchmarks/bench_scale.py --profile``)."""
    return json.dumps(model.model_json_schema())


@cache
def load_prompt(
    prompt_id: str, version: str | None = None, prompts_dir: Path = PROMPTS_DIR
) -> PromptTemplate:
    """Read ``<prompts_dir>/<prompt_id>.<version>.md``."""
    if prompt_id not in PAYLOADS:  # before the default-version lookup, which would KeyError
        raise PromptError(f"unknown prompt id {prompt_id!r}; known: {sorted(PAYLOADS)}")
    version = version or DEFAULT_VERSIONS[prompt_id]
    path = prompts_dir / f"{prompt_id}.{version}.md"
    if not path.is_file():
        raise PromptError(f"prompt template {path} not found")
    text = path.read_text(encoding="utf-8")
    parts = _SECTION.split(text)
    sections = {parts[i]: parts[i + 1].strip() for i in range(1, len(parts) - 1, 2)}
    if set(sections) != {"system", "user"}:
        raise PromptError(f"{path}: needs exactly a '## system' and a '## user' section")
    return PromptTemplate(prompt_id, version, sections["system"], sections["user"], path)


def property_set_id(properties: list[str]) -> str:
    """A short, stable name for a set of properties (the object prompt names the set it scores)."""
    digest = hashlib.sha256("\n".join(sorted(properties)).encode()).hexdigest()
    return f"ps-{digest[:12]}"


def format_list(items: list[str]) -> str:
    """One item per line, sorted: the rendering must not depend on input order."""
    return "\n".join(f"- {item}" for item in sorted(items))


def format_glossed_list(items: list[str], glosses: dict[str, str]) -> str:
    """``- name: gloss`` per line (``- name`` where no gloss is known), sorted by name."""
    return "\n".join(
        f"- {item}: {glosses[item]}" if glosses.get(item) else f"- {item}" for item in sorted(items)
    )
