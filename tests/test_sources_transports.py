"""Contract tests: LLMSource + live transports against local servers speaking each wire format.

Every test runs the real httpx code path against ``tests.servers.FakeServer`` on 127.0.0.1:
success, rate limits with Retry-After, 5xx, bodies that are not JSON, schema-invalid answers,
connections cut mid-body, 401, timeouts. The invariant: one valid record per success, nothing
recorded for failures, a bounded number of attempts, and the API key never in a record.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from email.utils import format_datetime
from pathlib import Path

import pytest
from servers import CutBody, FakeServer, Received, Reply, gemini_reply, openai_reply

from craft_e.compiler.cache import RecordCache
from craft_e.compiler.llm_knowledge import verb_call
from craft_e.compiler.sources.http_retry import MAX_RETRY_AFTER_S, parse_retry_after
from craft_e.compiler.sources.llm import (
    LLM_SOURCE,
    FatalTransportError,
    LLMSource,
    SourceError,
    Transport,
)
from craft_e.compiler.sources.transports import (
    GEMINI_BASE_URL,
    GEMINI_MODEL,
    OPENAI_BASE_URL,
    OPENAI_MODEL,
    GeminiTransport,
    OpenAITransport,
    gemini_schema,
    make_transport,
)
from craft_e.schemas.v1.records import Record

SECRET = "sk-test-SECRET-0123456789"
VALID = json.dumps({"verb": "cut", "properties": [{"name": "sharp edge", "weight": 0.9},
                                                   {"name": "rigid", "weight": 0.6}]})
SCHEMA_INVALID = json.dumps({"verb": "cut", "properties": [{"name": "sharp edge", "weight": 1.7}]})


@dataclass(frozen=True)
class Wire:
    """One provider's wire format: how to build its transport and how its server answers."""

    name: str
    model: str
    path: str  # the endpoint path the request must hit
    reply: Callable[[str], Reply]
    make: Callable[[str, float], Transport]


OPENAI = Wire(
    "openai", "test-model", "/v1/chat/completions", openai_reply,
    lambda url, t: OpenAITransport("test-model", url + "/v1", SECRET, timeout_s=t),
)
GEMINI = Wire(
    "gemini", "gemini-test", "/v1beta/models/gemini-test:generateContent", gemini_reply,
    lambda url, t: GeminiTransport("gemini-test", url + "/v1beta", SECRET, timeout_s=t),
)


@pytest.fixture(params=[OPENAI, GEMINI], ids=lambda w: w.name)
def wire(request: pytest.FixtureRequest) -> Wire:
    param: Wire = request.param
    return param


@dataclass
class Harness:
    """A fake server, a source wired to it, the cache, and the backoff sleeps it asked for."""

    server: FakeServer
    source: LLMSource
    cache: RecordCache
    sleeps: list[float]

    def records(self) -> list[Record]:
        return [r for _, r in self.cache.iter_records(LLM_SOURCE)]

    def cache_bytes(self) -> bytes:
        return b"".join(p.read_bytes() for p in sorted(self.cache.root.rglob("*")) if p.is_file())


@pytest.fixture
def harness_for(tmp_path: Path, wire: Wire) -> Iterator[Callable[..., Harness]]:
    servers: list[FakeServer] = []

    def start(*script: Reply | CutBody, timeout_s: float = 5.0, max_attempts: int = 3) -> Harness:
        server = FakeServer(script).__enter__()
        servers.append(server)
        sleeps: list[float] = []
        cache = RecordCache(tmp_path / "cache")
        source = LLMSource(cache=cache, provider=wire.name, model=wire.model,
                           transport=wire.make(server.url, timeout_s), max_attempts=max_attempts,
                           sleep=sleeps.append)
        return Harness(server, source, cache, sleeps)

    yield start
    for server in servers:
        server.__exit__(None, None, None)


def _only_record(h: Harness) -> Record:
    records = h.records()
    assert len(records) == 1
    return records[0]


def _assert_request_shape(wire: Wire, received: Received, call_record: Record) -> None:
    """The body carries the recorded model, the rendered messages and the response schema."""
    assert received.method == "POST" and received.route == wire.path
    body = received.json()
    messages = call_record.request.messages
    schema = call_record.request.response_schema
    if wire is OPENAI:
        assert received.headers["Authorization"] == f"Bearer {SECRET}"
        assert body["model"] == wire.model
        assert body["messages"] == [{"role": m.role, "content": m.content} for m in messages]
        assert body["temperature"] == 0.0
        fmt = body["response_format"]
        assert fmt["type"] == "json_schema"
        assert fmt["json_schema"]["schema"] == schema
        assert fmt["json_schema"]["name"] == "verb_properties_v1"
    else:
        assert received.headers["x-goog-api-key"] == SECRET
        assert body["systemInstruction"] == {"parts": [{"text": messages[0].content}]}
        assert body["contents"] == [{"role": "user", "parts": [{"text": messages[1].content}]}]
        config = body["generationConfig"]
        assert config["responseMimeType"] == "application/json"
        assert config["temperature"] == 0.0
        assert config["responseSchema"] == gemini_schema(schema)
    assert SECRET not in json.dumps(body)


def test_success_records_one_valid_record(wire: Wire, harness_for: Callable[..., Harness]) -> None:
    h = harness_for(wire.reply(VALID))
    record = h.source.fetch(verb_call("cut", version="v1"))
    assert _only_record(h) == record
    assert record.payload["properties"][0] == {"name": "sharp edge", "weight": 0.9}
    assert record.raw_response == VALID
    assert record.request.provider == wire.name and record.request.model == wire.model
    assert len(h.server.received) == 1
    _assert_request_shape(wire, h.server.received[0], record)
    assert SECRET.encode() not in h.cache_bytes()
    # cache-first: asking again answers from the record, the server sees nothing new
    assert h.source.fetch(verb_call("cut", version="v1")) == record
    assert len(h.server.received) == 1


def test_429_honours_retry_after_then_succeeds(wire: Wire, harness_for: Callable[..., Harness]) -> None:
    limited = Reply(429, {"error": {"message": "rate limited"}}, headers={"Retry-After": "3"})
    h = harness_for(limited, wire.reply(VALID))
    h.source.fetch(verb_call("cut", version="v1"))
    assert len(h.server.received) == 2
    assert h.sleeps == [3.0]  # the server's hint, longer than the 0.5 s base backoff
    _only_record(h)


def test_retry_after_is_bounded(wire: Wire, harness_for: Callable[..., Harness]) -> None:
    limited = Reply(429, {"error": {"message": "slow down"}}, headers={"Retry-After": "86400"})
    h = harness_for(limited, wire.reply(VALID))
    h.source.fetch(verb_call("cut", version="v1"))
    assert h.sleeps == [MAX_RETRY_AFTER_S]


def test_500_then_success(wire: Wire, harness_for: Callable[..., Harness]) -> None:
    h = harness_for(Reply(500, {"error": {"message": "internal"}}), wire.reply(VALID))
    h.source.fetch(verb_call("cut", version="v1"))
    assert len(h.server.received) == 2 and h.sleeps == [0.5]
    _only_record(h)


def test_body_that_is_not_json_is_retried(wire: Wire, harness_for: Callable[..., Harness]) -> None:
    h = harness_for(Reply(200, b"<html>upstream proxy error</html>"), wire.reply(VALID))
    h.source.fetch(verb_call("cut", version="v1"))
    assert len(h.server.received) == 2
    _only_record(h)


def test_unexpected_response_shape_is_retried(wire: Wire, harness_for: Callable[..., Harness]) -> None:
    h = harness_for(Reply(200, {"unexpected": True}), wire.reply(VALID))
    h.source.fetch(verb_call("cut", version="v1"))
    assert len(h.server.received) == 2
    _only_record(h)


def test_schema_invalid_answer_then_valid(wire: Wire, harness_for: Callable[..., Harness]) -> None:
    h = harness_for(wire.reply(SCHEMA_INVALID), wire.reply("not json at all"), wire.reply(VALID))
    record = h.source.fetch(verb_call("cut", version="v1"))
    assert len(h.server.received) == 3
    assert _only_record(h).raw_response == VALID == record.raw_response


def test_connection_cut_mid_body_then_success(wire: Wire, harness_for: Callable[..., Harness]) -> None:
    h = harness_for(CutBody(), wire.reply(VALID))
    h.source.fetch(verb_call("cut", version="v1"))
    assert len(h.server.received) == 2
    _only_record(h)


def test_401_is_fatal_and_names_the_key_variable(
    wire: Wire, harness_for: Callable[..., Harness]
) -> None:
    denied = Reply(401, {"error": {"message": f"Incorrect API key provided: {SECRET}"}})
    h = harness_for(denied, wire.reply(VALID))
    with pytest.raises(FatalTransportError) as caught:
        h.source.fetch(verb_call("cut", version="v1"))
    message = str(caught.value)
    assert "HTTP 401" in message
    assert ("OPENAI_API_KEY" if wire is OPENAI else "GEMINI_API_KEY") in message
    assert SECRET not in message  # scrubbed even when the server echoes it
    assert len(h.server.received) == 1 and h.records() == [] and h.sleeps == []


@pytest.mark.parametrize("status", [400, 403, 404])
def test_client_errors_are_fatal(
    wire: Wire, harness_for: Callable[..., Harness], status: int
) -> None:
    h = harness_for(Reply(status, {"error": {"message": "nope"}}))
    with pytest.raises(FatalTransportError, match=f"HTTP {status}"):
        h.source.fetch(verb_call("cut", version="v1"))
    assert len(h.server.received) == 1 and h.records() == []


def test_timeout_gives_source_error_after_bounded_attempts(
    wire: Wire, harness_for: Callable[..., Harness]
) -> None:
    slow = Reply(200, b"{}", delay_s=1.0)
    h = harness_for(slow, slow, timeout_s=0.2, max_attempts=2)
    with pytest.raises(SourceError, match="timed out") as caught:
        h.source.fetch(verb_call("cut", version="v1"))
    assert not isinstance(caught.value, FatalTransportError)
    assert "after 2 attempts" in str(caught.value)
    assert len(h.server.received) == 2 and h.records() == []


def test_persistent_failures_stop_after_max_attempts(
    wire: Wire, harness_for: Callable[..., Harness]
) -> None:
    h = harness_for(*[Reply(503, {"error": {"message": "overloaded"}})] * 5, max_attempts=3)
    with pytest.raises(SourceError, match="after 3 attempts"):
        h.source.fetch(verb_call("cut", version="v1"))
    assert len(h.server.received) == 3 and h.records() == []
    assert h.sleeps == [0.5, 1.0]


def test_truncated_answer_is_retried(wire: Wire, harness_for: Callable[..., Harness]) -> None:
    cut = openai_reply(VALID[:20], "length") if wire is OPENAI else gemini_reply(VALID[:20], "MAX_TOKENS")
    h = harness_for(cut, wire.reply(VALID))
    h.source.fetch(verb_call("cut", version="v1"))
    assert len(h.server.received) == 2
    _only_record(h)


# -- make_transport ------------------------------------------------------------------------


def test_make_transport_defaults() -> None:
    openai = make_transport("openai", None, None, env={"OPENAI_API_KEY": SECRET})
    gemini = make_transport("gemini", None, None, env={"GEMINI_API_KEY": SECRET})
    assert (openai.provider, openai.model) == ("openai", OPENAI_MODEL)
    assert (gemini.provider, gemini.model) == ("gemini", GEMINI_MODEL)
    assert isinstance(openai, OpenAITransport) and openai.base_url == OPENAI_BASE_URL
    assert isinstance(gemini, GeminiTransport) and gemini.base_url == GEMINI_BASE_URL
    assert SECRET not in repr(openai) and SECRET not in repr(gemini)


def test_make_transport_unknown_provider_names_choices() -> None:
    with pytest.raises(ValueError, match=r"unknown provider 'anthropic'.*openai, gemini"):
        make_transport("anthropic", None, None, env={})


@pytest.mark.parametrize(("provider", "variable"), [("openai", "OPENAI_API_KEY"),
                                                    ("gemini", "GEMINI_API_KEY")])
def test_missing_key_for_public_endpoint(provider: str, variable: str) -> None:
    with pytest.raises(ValueError, match=f"{variable} is not set"):
        make_transport(provider, None, None, env={})


def test_local_server_needs_no_key(tmp_path: Path) -> None:
    """A vLLM/Ollama/llama.cpp server: base URL given, no key, no Authorization header."""
    with FakeServer([openai_reply(VALID)]) as server:
        transport = make_transport("openai", "llama-3.1-8b", server.url + "/v1", env={})
        source = LLMSource(cache=RecordCache(tmp_path), provider="openai", model="llama-3.1-8b",
                           transport=transport, sleep=lambda s: None)
        source.fetch(verb_call("cut", version="v1"))
    assert "Authorization" not in server.received[0].headers
    assert server.received[0].json()["model"] == "llama-3.1-8b"


def test_gemini_schema_uses_the_openapi_subset() -> None:
    schema = verb_call("cut", version="v1").template.response_schema()
    converted = gemini_schema(schema)
    text = json.dumps(converted)
    assert "$ref" not in text and "$defs" not in text and "additionalProperties" not in text
    assert converted["type"] == "OBJECT"
    item = converted["properties"]["properties"]["items"]
    assert item["type"] == "OBJECT" and item["properties"]["weight"]["maximum"] == 1.0
    assert item["required"] == ["name", "weight"]
    nullable = gemini_schema({"anyOf": [{"type": "string"}, {"type": "null"}]})
    assert nullable == {"type": "STRING", "nullable": True}


def test_parse_retry_after() -> None:
    now = datetime(2025, 1, 1, tzinfo=UTC)
    assert parse_retry_after("2.5") == 2.5
    assert parse_retry_after("-4") == 0.0
    assert parse_retry_after("9999") == MAX_RETRY_AFTER_S
    assert parse_retry_after(format_datetime(now + timedelta(seconds=7), usegmt=True), now) == 7.0
    assert parse_retry_after("soon") is None and parse_retry_after(None) is None
