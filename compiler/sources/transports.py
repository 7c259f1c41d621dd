"""Live LLM transports: the OpenAI chat-completions and Gemini generateContent wire formats.

A transport turns one ``RecordRequest`` into one HTTP call and returns the model's text answer;
``LLMSource`` owns caching, validation and retries. Transports only classify failures
(``TransportError`` retryable, ``FatalTransportError`` not, see ``http_retry``) and never see or
write records, so an API key cannot leak into the cache: keys come from the environment, live in
the HTTP client's default headers and are scrubbed from every error message.

``OpenAITransport`` speaks to any OpenAI-compatible server (OpenAI, vLLM, Ollama, llama.cpp
server); ``GeminiTransport`` to Google's Generative Language API.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from typing import Any

import httpx

from ...schemas.v1.records import RecordRequest
from .http_retry import make_client, response_json, send
from .llm import FatalTransportError, Transport, TransportError

OPENAI_BASE_URL = "https://api.openai.com/v1"
OPENAI_MODEL = "gpt-4o-mini"
OPENAI_KEY_ENV = "OPENAI_API_KEY"
GEMINI_BASE_URL = "https://generativelanguage.googleapis.com/v1beta"
GEMINI_MODEL = "gemini-2.5-flash"
GEMINI_KEY_ENV = "GEMINI_API_KEY"
PROVIDERS = ("openai", "gemini")

#: Decoding parameters spelled the OpenAI way, as Gemini's ``generationConfig`` spells them.
_GEMINI_PARAMS = {
    "temperature": "temperature",
    "top_p": "topP",
    "top_k": "topK",
    "max_tokens": "maxOutputTokens",
    "max_output_tokens": "maxOutputTokens",
    "seed": "seed",
    "stop": "stopSequences",
    "presence_penalty": "presencePenalty",
    "frequency_penalty": "frequencyPenalty",
}
#: Keys of Gemini's ``Schema`` (an OpenAPI 3.0 subset); JSON-Schema-only keys are dropped.
_GEMINI_SCHEMA_KEYS = frozenset({
    "type", "format", "title", "description", "nullable", "enum", "maxItems", "minItems",
    "properties", "required", "minProperties", "maxProperties", "minLength", "maxLength",
    "pattern", "anyOf", "propertyOrdering", "items", "minimum", "maximum",
})
_MAX_SCHEMA_DEPTH = 32


class _HTTPTransport:
    """What both wire formats share: base URL, model, one pooled client, secret scrubbing."""

    provider: str
    key_env: str

    def __init__(
        self,
        model: str,
        base_url: str,
        api_key: str | None,
        *,
        timeout_s: float | None = None,
        client: httpx.Client | None = None,
    ) -> None:
        self.model = model
        self.base_url = base_url.rstrip("/")
        self._secrets: tuple[str, ...] = (api_key,) if api_key else ()
        self._client = client or make_client(timeout_s, self._auth_headers(api_key))

    def __repr__(self) -> str:  # no key in reprs: they end up in tracebacks and logs
        return f"{type(self).__name__}(model={self.model!r}, base_url={self.base_url!r})"

    def _auth_headers(self, api_key: str | None) -> dict[str, str]:
        raise NotImplementedError

    def close(self) -> None:
        self._client.close()

    def _post(self, url: str, body: dict[str, Any], what: str) -> Any:
        response = send(self._client, "POST", url, what=what, json_body=body,
                        key_env=self.key_env, secrets=self._secrets)
        return response_json(response, what)


class OpenAITransport(_HTTPTransport):
    """``POST {base_url}/chat/completions`` with a ``json_schema`` response format.

    llama-cpp-python's server (``python -m llama_cpp.server``, 0.3.x) rejects OpenAI's
    ``{"type": "json_schema", ...}`` (its error handler answers HTTP 500 with the validation
    error naming ``response_format``; FastAPI alone would say 422) and takes the schema as
    ``{"type": "json_object", "schema": ...}`` instead, compiled into a grammar. On such a
    rejection the transport resends once in that form and keeps using it; the record key does
    not depend on the wire form, so records stay the same either way.
    """

    provider = "openai"
    key_env = OPENAI_KEY_ENV
    #: ``json_schema`` (OpenAI, vLLM, Ollama, llama.cpp's C++ server) or ``json_object``.
    schema_format = "json_schema"

    def _auth_headers(self, api_key: str | None) -> dict[str, str]:
        return {"Authorization": f"Bearer {api_key}"} if api_key else {}

    def request_body(self, request: RecordRequest) -> dict[str, Any]:
        """The chat-completions body: the recorded model, messages and decoding parameters."""
        body: dict[str, Any] = {
            "model": request.model,
            "messages": [{"role": m.role, "content": m.content} for m in request.messages],
            **request.params,
        }
        if request.response_schema and self.schema_format == "json_object":
            body["response_format"] = {
                "type": "json_object", "schema": grammar_schema(request.response_schema)
            }
        elif request.response_schema:
            body["response_format"] = {
                "type": "json_schema",
                "json_schema": {
                    "name": schema_name(request.prompt),
                    "schema": request.response_schema,
                    # strict mode demands every property be required; pydantic schemas with
                    # defaults would be rejected, and the answer is validated anyway.
                    "strict": False,
                },
            }
        return body

    def complete(self, request: RecordRequest) -> str:
        what = f"openai {request.model} {request.prompt} subject={request.subject!r}"
        url = f"{self.base_url}/chat/completions"
        try:
            data = self._post(url, self.request_body(request), what)
        except (FatalTransportError, TransportError) as exc:
            if not (request.response_schema and self.schema_format == "json_schema"
                    and rejects_json_schema(str(exc))):
                raise
            self.schema_format = "json_object"
            try:
                data = self._post(url, self.request_body(request), what)
            except (FatalTransportError, TransportError):
                self.schema_format = "json_schema"
                raise exc from None
        return openai_answer_text(data, what)


#: A weight in [0, 1] as a grammar can bound it: llama.cpp's schema-to-grammar converter
#: ignores ``minimum``/``maximum`` on numbers, so a schema sent in the ``json_object`` form
#: enumerates the weights in steps of 0.05 instead (the answer is still validated by pydantic).
UNIT_WEIGHTS = tuple(round(i * 0.05, 2) for i in range(21))
#: Names (strings of at most this many characters: verbs, objects, properties) are sent to a
#: grammar as the lowercase phrases every prompt asks for; a small model otherwise copies the
#: "..." placeholder of the prompt's example answer. Longer strings (definitions) stay free.
NAME_MAX_LENGTH = 64


def grammar_schema(schema: Any) -> Any:
    """``schema`` narrowed for a grammar-constrained server (``json_object`` form): numbers in
    [0, 1] as an enum of ``UNIT_WEIGHTS``, short names as lowercase phrases. Whatever the
    narrowed schema admits, the original admits too."""
    if isinstance(schema, list):
        return [grammar_schema(item) for item in schema]
    if not isinstance(schema, Mapping):
        return schema
    out = {key: grammar_schema(value) for key, value in schema.items()}
    if out.get("type") == "number" and out.get("minimum") == 0 and out.get("maximum") == 1:
        out["enum"] = list(UNIT_WEIGHTS)
    longest = out.get("maxLength")
    if (out.get("type") == "string" and "pattern" not in out and isinstance(longest, int)
            and out.get("minLength", 0) >= 1 and longest <= NAME_MAX_LENGTH):
        out["pattern"] = f"^[a-z][a-z0-9 '-]{{0,{longest - 1}}}$"
    return out


def rejects_json_schema(message: str) -> bool:
    """An HTTP 400/422/500 naming ``response_format`` and ``json_schema``: the server wants the
    schema in another form (llama-cpp-python: ``json_object`` + ``schema``)."""
    status = re.search(r"HTTP (\d{3})\b", message)
    return (status is not None and status.group(1) in {"400", "422", "500"}
            and "response_format" in message and "json_schema" in message)


class GeminiTransport(_HTTPTransport):
    """``POST {base_url}/models/{model}:generateContent`` with a JSON response schema."""

    provider = "gemini"
    key_env = GEMINI_KEY_ENV

    def _auth_headers(self, api_key: str | None) -> dict[str, str]:
        # A header, not ?key=: URLs end up in proxy logs and exception texts.
        return {"x-goog-api-key": api_key} if api_key else {}

    def request_body(self, request: RecordRequest) -> dict[str, Any]:
        """contents + systemInstruction + generationConfig (JSON mime type and schema)."""
        system = [m.content for m in request.messages if m.role == "system"]
        contents = [
            {"role": "model" if m.role == "assistant" else "user", "parts": [{"text": m.content}]}
            for m in request.messages
            if m.role != "system"
        ]
        config: dict[str, Any] = {_GEMINI_PARAMS.get(k, k): v for k, v in request.params.items()}
        config["responseMimeType"] = "application/json"
        if request.response_schema:
            config["responseSchema"] = gemini_schema(request.response_schema)
        body: dict[str, Any] = {"contents": contents, "generationConfig": config}
        if system:
            body["systemInstruction"] = {"parts": [{"text": "\n\n".join(system)}]}
        return body

    def complete(self, request: RecordRequest) -> str:
        what = f"gemini {request.model} {request.prompt} subject={request.subject!r}"
        model = request.model.removeprefix("models/")
        url = f"{self.base_url}/models/{model}:generateContent"
        return gemini_answer_text(self._post(url, self.request_body(request), what), what)


def schema_name(prompt_ref: str) -> str:
    """OpenAI wants ``^[a-zA-Z0-9_-]{1,64}$`` for a schema name; prompt refs contain ``@``."""
    return re.sub(r"[^A-Za-z0-9_-]", "_", prompt_ref)[:64] or "answer"


def openai_answer_text(data: Any, what: str) -> str:
    """``choices[0].message.content``; anything else the server sent is a retryable error."""
    choices = data.get("choices") if isinstance(data, dict) else None
    if not isinstance(choices, list) or not choices or not isinstance(choices[0], dict):
        raise TransportError(f"{what}: unexpected response, no choices: {str(data)[:160]}")
    choice = choices[0]
    message = choice.get("message")
    if not isinstance(message, dict):
        raise TransportError(f"{what}: unexpected response, choice without a message")
    if choice.get("finish_reason") == "length":
        raise TransportError(f"{what}: answer cut off at the token limit (finish_reason=length)")
    if message.get("refusal"):
        raise TransportError(f"{what}: the model refused: {str(message['refusal'])[:160]}")
    content = message.get("content")
    if isinstance(content, list):  # some compatible servers send content parts
        content = "".join(p.get("text", "") for p in content if isinstance(p, dict))
    if not isinstance(content, str) or not content.strip():
        raise TransportError(f"{what}: the answer has no text content")
    return content


def gemini_answer_text(data: Any, what: str) -> str:
    """The text parts of ``candidates[0]``; blocks, truncation and odd shapes are retryable."""
    candidates = data.get("candidates") if isinstance(data, dict) else None
    if not isinstance(candidates, list) or not candidates or not isinstance(candidates[0], dict):
        feedback = data.get("promptFeedback") if isinstance(data, dict) else None
        reason = feedback.get("blockReason") if isinstance(feedback, dict) else None
        detail = f"prompt blocked ({reason})" if reason else f"no candidates: {str(data)[:160]}"
        raise TransportError(f"{what}: unexpected response, {detail}")
    candidate = candidates[0]
    finish = candidate.get("finishReason")
    if finish == "MAX_TOKENS":
        raise TransportError(f"{what}: answer cut off at the token limit (finishReason=MAX_TOKENS)")
    content = candidate.get("content")
    parts = content.get("parts") if isinstance(content, dict) else None
    texts = [
        p["text"] for p in parts or []
        if isinstance(p, dict) and isinstance(p.get("text"), str) and not p.get("thought")
    ]
    if not texts or not "".join(texts).strip():
        raise TransportError(f"{what}: the answer has no text (finishReason={finish})")
    return "".join(texts)


def gemini_schema(schema: Mapping[str, Any]) -> dict[str, Any]:
    """A pydantic JSON Schema rewritten into Gemini's ``Schema`` subset.

    Gemini rejects ``$defs``/``$ref`` and ``additionalProperties``, so references are inlined,
    unknown keys dropped, ``anyOf [X, null]`` becomes ``nullable`` and types are upper-cased.
    """
    defs = schema.get("$defs", {})
    return _gemini_node(schema, defs, 0)


def _gemini_node(node: Mapping[str, Any], defs: Mapping[str, Any], depth: int) -> dict[str, Any]:
    if depth > _MAX_SCHEMA_DEPTH:
        raise ValueError("response schema nests too deeply (recursive $ref?) for Gemini")
    ref = node.get("$ref")
    if isinstance(ref, str):
        target = defs.get(ref.rsplit("/", 1)[-1])
        if not isinstance(target, Mapping):
            raise ValueError(f"response schema reference {ref!r} has no definition")
        merged = {**target, **{k: v for k, v in node.items() if k != "$ref"}}
        return _gemini_node(merged, defs, depth + 1)
    options = node.get("anyOf")
    if isinstance(options, list):
        real = [o for o in options if not (isinstance(o, Mapping) and o.get("type") == "null")]
        if len(real) == 1 and len(real) < len(options):
            rest = {k: v for k, v in node.items() if k != "anyOf"}
            return {**_gemini_node({**real[0], **rest}, defs, depth + 1), "nullable": True}
    out: dict[str, Any] = {}
    for key, value in node.items():
        if key not in _GEMINI_SCHEMA_KEYS:
            continue
        if key == "type" and isinstance(value, str):
            out[key] = value.upper()
        elif key == "properties" and isinstance(value, Mapping):
            out[key] = {name: _gemini_node(sub, defs, depth + 1) for name, sub in value.items()}
        elif key == "items" and isinstance(value, Mapping):
            out[key] = _gemini_node(value, defs, depth + 1)
        elif key == "anyOf" and isinstance(value, list):
            out[key] = [_gemini_node(sub, defs, depth + 1) for sub in value]
        else:
            out[key] = value
    return out


def make_transport(
    provider: str,
    model: str | None = None,
    base_url: str | None = None,
    *,
    timeout_s: float | None = None,
    env: Mapping[str, str] | None = None,
) -> Transport:
    """The live transport for ``provider``, its key read from the environment.

    A key is required for the public endpoints; with ``base_url`` (a self-hosted vLLM, Ollama or
    llama.cpp server, a proxy) it is optional. Raises ``ValueError`` naming the fix for an
    unknown provider or a missing key.
    """
    environ = os.environ if env is None else env
    if provider == "openai":
        key = environ.get(OPENAI_KEY_ENV) or None
        _require_key(provider, key, base_url, OPENAI_KEY_ENV)
        return OpenAITransport(model or OPENAI_MODEL, base_url or OPENAI_BASE_URL, key,
                               timeout_s=timeout_s)
    if provider == "gemini":
        key = environ.get(GEMINI_KEY_ENV) or None
        _require_key(provider, key, base_url, GEMINI_KEY_ENV)
        return GeminiTransport(model or GEMINI_MODEL, base_url or GEMINI_BASE_URL, key,
                               timeout_s=timeout_s)
    raise ValueError(
        f"unknown provider {provider!r}; choose one of {', '.join(PROVIDERS)} "
        f"(or 'replay', which needs no transport)"
    )


def _require_key(provider: str, key: str | None, base_url: str | None, key_env: str) -> None:
    if key is None and base_url is None:
        raise ValueError(
            f"{provider}: {key_env} is not set; export {key_env}=<your key>, or pass --base-url "
            f"for a local server that needs no key"
        )


__all__ = [
    "FatalTransportError",
    "GeminiTransport",
    "OpenAITransport",
    "TransportError",
    "gemini_schema",
    "make_transport",
]
