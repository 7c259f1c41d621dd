"""A recorded source response: ``artifacts/cache/<source>/<key>.json``.

The key is the sha256 of the canonical JSON of the request identity (provider, model, prompt
id@version, rendered messages, decoding params, response JSON schema), so any change of prompt,
model or schema addresses a different record. API keys are never part of a request.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field


def canonical_json(value: Any) -> str:
    """The one JSON spelling used for hashing: sorted keys, no spaces, UTF-8 kept."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False)


class Message(BaseModel):
    """One chat message of a rendered prompt."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    role: Literal["system", "user", "assistant"]
    content: str


class RecordRequest(BaseModel):
    """Everything that identifies a request; its canonical JSON hashes to the record key."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    provider: str = Field(description="who produced the answer: curated, openai, gemini, ...")
    model: str
    prompt: str = Field(description="prompt id@version, e.g. verb_properties@v1")
    messages: list[Message]
    params: dict[str, Any] = Field(default_factory=dict, description="decoding parameters")
    response_schema: dict[str, Any] = Field(default_factory=dict)
    subject: str = Field(
        description="the verb or object the prompt asks about (an index, in the key)"
    )
    variables: dict[str, Any] = Field(
        default_factory=dict, description="template variables (e.g. the named property set)"
    )

    def key(self) -> str:
        """Content address of this request."""
        return hashlib.sha256(canonical_json(self.model_dump(mode="json")).encode()).hexdigest()


class Record(BaseModel):
    """A request with its raw response and the parsed, validated payload."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    schema_id: Literal["https://craft-e.dev/schemas/v1/record.json"] = (
        "https://craft-e.dev/schemas/v1/record.json"
    )
    key: str = Field(pattern=r"^[0-9a-f]{64}$")
    source: str = Field(description="cache folder: llm, conceptnet, ...")
    request: RecordRequest
    raw_response: str
    payload: dict[str, Any]
    note: str = Field(default="", description="free text from the author or the transport")
