"""Batch providers against wire transcripts of the documented OpenAI Batch / Gemini Batch formats.

The transcripts (``tests/fixtures/batch/*_transcript.json``, bodies in ``*.jsonl``) hold what each
API answers, exchange by exchange, for one batch of four stage-1 requests (cut, pour, dig,
scoop): dig fails on the provider's side, scoop answers outside the schema. A local
``FakeServer`` plays them back over real HTTP; the tests check what the client sent (the
documented input format, each body identical to the synchronous transport's), what it stored
(the synchronous provider's keys, so the records replay), how it reports failed subjects, and
that it resumes a recorded batch id after a crash instead of submitting a new batch.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from email.parser import BytesParser
from email.policy import default as email_policy
from pathlib import Path
from typing import Any

import pytest
from servers import FakeServer, Received, Reply
from typer.testing import CliRunner

from craft_e.compiler.cache import RecordCache
from craft_e.compiler.cli import app
from craft_e.compiler.llm_knowledge import verb_call
from craft_e.compiler.sources.batch import (
    BatchFailedError,
    BatchLLMSource,
    GeminiBatch,
    OpenAIBatch,
    read_state,
    state_dir,
)
from craft_e.compiler.sources.llm import LLM_SOURCE, LLMSource, PromptCall, SourceError
from craft_e.compiler.sources.transports import GeminiTransport, OpenAITransport
from craft_e.schemas.v1.records import RecordRequest

BATCH_FIXTURES = Path(__file__).resolve().parent / "fixtures" / "batch"
KB_SMALL = Path(__file__).resolve().parent / "fixtures" / "kb_small"
SECRET = "sk-test-BATCH-SECRET-42"
VERBS = ["cut", "pour", "dig", "scoop"]
ANSWERED = {"cut": "sharp edge", "pour": "holds liquid"}


class CrashError(Exception):
    """Stands in for a killed process: raised from the poll loop's sleep."""


def exchanges(name: str) -> list[dict[str, Any]]:
    data = json.loads((BATCH_FIXTURES / name).read_text(encoding="utf-8"))
    out: list[dict[str, Any]] = data["exchanges"]
    return out


def replies(items: list[dict[str, Any]], server_url: str) -> list[Reply]:
    out = []
    for item in items:
        response = item["response"]
        headers = {k: v.replace("{server}", server_url) for k, v in response.get("headers", {}).items()}
        if "json" in response:
            body: Any = response["json"]
        elif "body_file" in response:
            body = (BATCH_FIXTURES / response["body_file"]).read_bytes()
        else:
            body = response.get("text", "")
        out.append(Reply(response["status"], body, headers=headers))
    return out


def routes(items: list[dict[str, Any]]) -> list[tuple[str, str]]:
    return [(i["request"]["method"], i["request"]["path"]) for i in items]


@dataclass(frozen=True)
class Case:
    name: str
    transcript: str
    make: Callable[[str], OpenAIBatch | GeminiBatch]
    sleeps: list[float]  # the poll back-off the transcript implies (poll_s = 10, factor 1.5)


def _gemini_file(url: str) -> GeminiBatch:
    backend = GeminiBatch("gemini-test", url + "/v1beta", SECRET)
    backend.inline_limit_bytes = 0  # force the JSONL-file input
    return backend


CASES = [
    Case("openai", "openai_transcript.json",
         lambda url: OpenAIBatch("gpt-test", url + "/v1", SECRET), [10.0, 15.0]),
    Case("gemini-inline", "gemini_inline_transcript.json",
         lambda url: GeminiBatch("gemini-test", url + "/v1beta", SECRET), [10.0]),
    Case("gemini-file", "gemini_file_transcript.json", _gemini_file, []),
]


@pytest.fixture
def serve() -> Iterator[Callable[[list[dict[str, Any]]], FakeServer]]:
    servers: list[FakeServer] = []

    def start(items: list[dict[str, Any]]) -> FakeServer:
        server = FakeServer().__enter__()
        servers.append(server)
        server.script.extend(replies(items, server.url))
        return server

    yield start
    for server in servers:
        server.__exit__(None, None, None)


def calls(verbs: list[str] = VERBS) -> list[PromptCall]:
    return [verb_call(v, version="v1") for v in verbs]


def sync_request(backend: OpenAIBatch | GeminiBatch, verb: str) -> RecordRequest:
    """The request the *synchronous* provider would send and key (provider openai/gemini)."""
    sync = LLMSource(RecordCache(Path("/nonexistent")), provider=backend.provider, model=backend.model)
    return sync.request_for(verb_call(verb, version="v1"))


def batch_source(cache: RecordCache, backend: OpenAIBatch | GeminiBatch, sleep: Callable[[float], None],
                 **kwargs: Any) -> BatchLLMSource:
    return BatchLLMSource(cache=cache, provider=backend.provider, model=backend.model,
                          backend=backend, sleep=sleep, **kwargs)


def sent_inputs(case: Case, received: list[Received]) -> list[tuple[str, dict[str, Any]]]:
    """(custom_id, request body) per line of the batch input the client submitted."""
    if case.name == "openai":
        upload = received[0]
        raw = b"Content-Type: " + upload.headers["Content-Type"].encode() + b"\r\n\r\n" + upload.body
        parts = {p.get_param("name", header="content-disposition"): p
                 for p in BytesParser(policy=email_policy).parsebytes(raw).iter_parts()}
        assert parts["purpose"].get_content().strip() == "batch"
        jsonl = parts["file"].get_payload(decode=True)
        rows = [json.loads(line) for line in jsonl.decode().splitlines()]
        for row in rows:
            assert set(row) == {"custom_id", "method", "url", "body"}
            assert row["method"] == "POST" and row["url"] == "/v1/chat/completions"
        create = received[1].json()
        assert create["input_file_id"] == "file-abc123"
        assert create["endpoint"] == "/v1/chat/completions" and create["completion_window"] == "24h"
        return [(r["custom_id"], r["body"]) for r in rows]
    if case.name == "gemini-inline":
        batch = received[0].json()["batch"]
        inlined = batch["input_config"]["requests"]["requests"]
        return [(r["metadata"]["key"], r["request"]) for r in inlined]
    start, upload, create = received[0], received[1], received[2]
    assert start.headers["X-Goog-Upload-Protocol"] == "resumable"
    assert start.headers["X-Goog-Upload-Command"] == "start"
    assert int(start.headers["X-Goog-Upload-Header-Content-Length"]) == len(upload.body)
    assert upload.headers["X-Goog-Upload-Command"] == "upload, finalize"
    assert upload.query == {"upload_id": "ADPycdtE7x", "upload_protocol": "resumable"}
    assert create.json()["batch"]["input_config"] == {"file_name": "files/input-7kq2"}
    rows = [json.loads(line) for line in upload.body.decode().splitlines()]
    return [(r["key"], r["request"]) for r in rows]


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_batch_transcript_records_sync_keys_and_names_failures(
    case: Case, tmp_path: Path, serve: Callable[[list[dict[str, Any]]], FakeServer]
) -> None:
    items = exchanges(case.transcript)
    server = serve(items)
    backend = case.make(server.url)
    cache = RecordCache(tmp_path / "cache")
    sleeps: list[float] = []
    source = batch_source(cache, backend, sleeps.append)
    with pytest.raises(BatchFailedError) as caught:
        source.fetch_many(calls())

    # the exchange followed the documented sequence, nothing more
    assert [(r.method, r.route) for r in server.received] == routes(items)
    assert sleeps == case.sleeps
    # the input: one request per missing record, each body what the synchronous transport sends
    sync_body: Callable[[RecordRequest], dict[str, Any]] = (
        OpenAITransport(backend.model, backend.base_url, None).request_body if case.name == "openai"
        else GeminiTransport(backend.model, backend.base_url, None).request_body
    )
    sent = sent_inputs(case, server.received)
    assert [cid for cid, _ in sent] == [f"req-{i:06d}" for i in range(4)]
    for (_, body), verb in zip(sent, VERBS, strict=True):
        assert body == sync_body(sync_request(backend, verb))
    header = "Authorization" if case.name == "openai" else "x-goog-api-key"
    assert all(SECRET in r.headers[header] for r in server.received)

    # failed items are named by prompt and subject, with the provider's reason
    failed = caught.value.failed
    assert set(failed) == {"verb_properties@v1 subject='dig'", "verb_properties@v1 subject='scoop'"}
    assert ("HTTP 500" if case.name == "openai" else "INTERNAL") in failed["verb_properties@v1 subject='dig'"]
    assert "invalid payload" in failed["verb_properties@v1 subject='scoop'"]
    message = str(caught.value)
    assert "2 of 4 requests" in message and "subject='dig'" in message and "run the same command" in message

    # the answered ones are stored under the synchronous provider's keys and replay as such
    records = {r.request.subject: r for _, r in cache.iter_records(LLM_SOURCE)}
    assert set(records) == set(ANSWERED)
    replay = LLMSource(cache, provider=backend.provider, model=backend.model)
    for verb, prop in ANSWERED.items():
        record = records[verb]
        assert record.key == sync_request(backend, verb).key()
        assert record.request.provider == backend.provider and record.request.model == backend.model
        assert record.payload["properties"][0]["name"] == prop
        assert replay.fetch(verb_call(verb, version="v1")) == record
    assert SECRET.encode() not in b"".join(p.read_bytes() for p in cache.root.rglob("*") if p.is_file())
    assert list(state_dir(cache.root).glob("*.json")) == []  # the batch is over: no state left
    assert cache.verify().ok


def test_openai_resumes_the_recorded_batch_after_a_crash(
    tmp_path: Path, serve: Callable[[list[dict[str, Any]]], FakeServer]
) -> None:
    items = exchanges("openai_transcript.json")
    cache = RecordCache(tmp_path / "cache")
    first = serve(items[:3])  # upload, create, one poll: then the process dies while waiting

    def crash(_: float) -> None:
        raise CrashError

    backend = OpenAIBatch("gpt-test", first.url + "/v1", SECRET)
    with pytest.raises(CrashError):
        batch_source(cache, backend, crash).fetch_many(calls())
    states = list(state_dir(cache.root).glob("openai-batch-*.json"))
    assert len(states) == 1
    state = read_state(states[0])
    assert state["batch_id"] == "batch_abc123" and state["input_file_id"] == "file-abc123"
    assert state["items"] == {f"req-{i:06d}": sync_request(backend, v).key()
                              for i, v in enumerate(VERBS)}
    assert list(cache.iter_records(LLM_SOURCE)) == []
    assert cache.verify().ok  # the state folder is not a record source

    second = serve(items[3:])  # the same batch, polled by a new process
    backend = OpenAIBatch("gpt-test", second.url + "/v1", SECRET)
    sleeps: list[float] = []
    with pytest.raises(BatchFailedError) as caught:
        batch_source(cache, backend, sleeps.append).fetch_many(calls())
    assert [r.method for r in second.received] == ["GET"] * 4  # nothing new submitted
    assert [r.route for r in second.received][:2] == ["/v1/batches/batch_abc123"] * 2
    assert set(caught.value.failed) == {"verb_properties@v1 subject='dig'",
                                        "verb_properties@v1 subject='scoop'"}
    assert {r.request.subject for _, r in cache.iter_records(LLM_SOURCE)} == set(ANSWERED)
    assert list(state_dir(cache.root).glob("*.json")) == []


def _batch_object(status: str, **extra: Any) -> dict[str, Any]:
    return {"id": "batch_r2", "object": "batch", "endpoint": "/v1/chat/completions",
            "status": status, "input_file_id": "file-r2", "output_file_id": None,
            "error_file_id": None, "errors": None,
            "request_counts": {"total": 2, "completed": 0, "failed": 0}, **extra}


def test_rerun_submits_only_the_failed_items(
    tmp_path: Path, serve: Callable[[list[dict[str, Any]]], FakeServer]
) -> None:
    cache = RecordCache(tmp_path / "cache")
    server = serve(exchanges("openai_transcript.json"))
    backend = OpenAIBatch("gpt-test", server.url + "/v1", SECRET)
    with pytest.raises(BatchFailedError):
        batch_source(cache, backend, lambda s: None).fetch_many(calls())
    answers = {"req-000000": {"verb": "dig", "properties": [{"name": "pointed blade", "weight": 0.9}]},
               "req-000001": {"verb": "scoop", "properties": [{"name": "concave bowl", "weight": 0.9}]}}
    output = "".join(json.dumps({"id": f"b{cid}", "custom_id": cid, "error": None, "response": {
        "status_code": 200, "body": {"choices": [{"index": 0, "finish_reason": "stop", "message": {
            "role": "assistant", "content": json.dumps(a)}}]}}}) + "\n" for cid, a in answers.items())
    again = serve([])
    again.script.extend([
        Reply(200, {"id": "file-r2", "object": "file", "purpose": "batch"}),
        Reply(200, _batch_object("validating")),
        Reply(200, _batch_object("completed", output_file_id="file-o2")),
        Reply(200, output.encode()),
    ])
    backend = OpenAIBatch("gpt-test", again.url + "/v1", SECRET)
    records = batch_source(cache, backend, lambda s: None).fetch_many(calls())
    assert [r.request.subject for r in records] == VERBS
    upload = again.received[0].body.decode()
    assert upload.count('"custom_id"') == 2 and '"dig' in upload and '"scoop' in upload


def test_failed_batch_fails_every_item_with_the_reason(
    tmp_path: Path, serve: Callable[[list[dict[str, Any]]], FakeServer]
) -> None:
    server = serve([])
    failed = _batch_object("failed", errors={"object": "list", "data": [
        {"code": "invalid_json_line", "message": "This line is not parseable as valid JSON.", "line": 2}]})
    server.script.extend([Reply(200, {"id": "file-r2"}), Reply(200, _batch_object("validating")),
                          Reply(200, failed)])
    cache = RecordCache(tmp_path / "cache")
    backend = OpenAIBatch("gpt-test", server.url + "/v1", SECRET)
    with pytest.raises(BatchFailedError) as caught:
        batch_source(cache, backend, lambda s: None).fetch_many(calls(["cut", "pour"]))
    assert set(caught.value.failed) == {"verb_properties@v1 subject='cut'", "verb_properties@v1 subject='pour'"}
    assert all("invalid_json_line" in why for why in caught.value.failed.values())
    assert list(cache.iter_records(LLM_SOURCE)) == []


def test_batch_wait_limit_keeps_the_state_for_resume(
    tmp_path: Path, serve: Callable[[list[dict[str, Any]]], FakeServer]
) -> None:
    items = exchanges("openai_transcript.json")
    server = serve(items[:3])
    cache = RecordCache(tmp_path / "cache")
    backend = OpenAIBatch("gpt-test", server.url + "/v1", SECRET)
    source = batch_source(cache, backend, lambda s: None, max_wait_s=5.0)
    with pytest.raises(SourceError, match=r"batch_abc123 still in_progress.*run the same command"):
        source.fetch_many(calls())
    assert len(list(state_dir(cache.root).glob("openai-batch-*.json"))) == 1


def test_cached_requests_are_not_submitted(
    tmp_path: Path, serve: Callable[[list[dict[str, Any]]], FakeServer]
) -> None:
    """A batch holds only the misses; with everything recorded no request is made at all."""
    server = serve(exchanges("openai_transcript.json"))
    cache = RecordCache(tmp_path / "cache")
    backend = OpenAIBatch("gpt-test", server.url + "/v1", SECRET)
    with pytest.raises(BatchFailedError):
        batch_source(cache, backend, lambda s: None).fetch_many(calls())
    seen = len(server.received)
    records = batch_source(cache, backend, lambda s: None).fetch_many(calls(["pour", "cut"]))
    assert [r.request.subject for r in records] == ["pour", "cut"]
    assert len(server.received) == seen


def test_cli_batch_failure_exits_3_naming_subjects(
    tmp_path: Path, serve: Callable[[list[dict[str, Any]]], FakeServer]
) -> None:
    server = serve([])
    failed = _batch_object("failed", errors={"object": "list", "data": [
        {"code": "model_not_found", "message": "The model does not exist."}]})
    server.script.extend([Reply(200, {"id": "file-r2"}), Reply(200, _batch_object("validating")),
                          Reply(200, failed)])
    result = CliRunner().invoke(app, [
        "build", "--verbs", str(KB_SMALL / "verbs.txt"), "--objects", str(KB_SMALL / "objects.txt"),
        "--provider", "openai-batch", "--base-url", server.url + "/v1", "--model", "gpt-test",
        "--prompts", "v1", "--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "kb"),
        "--name", "batch-kb", "--quiet",
    ], env={"COLUMNS": "2000", "OPENAI_API_KEY": ""})
    assert result.exit_code == 3, result.output
    text = result.output.replace("\n", " ")
    assert "openai-batch: 3 of 3 requests got no valid answer" in text
    for verb in ("cut", "scoop", "pour"):
        assert f"subject='{verb}'" in text
    assert "model_not_found" in text
    assert not (tmp_path / "kb").exists()


class BatchService:
    """A stateful OpenAI Batch API stand-in that answers from the kb_small fixture answers.

    It speaks the same exchanges as the transcript (upload, create, poll, output file) and
    answers each request of a batch by its prompt and subject, so a whole two-stage build can
    run through ``--provider openai-batch``.
    """

    def __init__(self) -> None:
        self.answers: dict[tuple[str, str], dict[str, Any]] = {}
        for name, field_name in (("verb_properties", "verb"), ("object_properties", "object")):
            for line in (KB_SMALL / f"{name}.jsonl").read_text(encoding="utf-8").splitlines():
                if line.strip() and not line.startswith(("//", "#")):
                    payload = json.loads(line)
                    self.answers[(name, payload[field_name])] = payload
        self.inputs: list[list[dict[str, Any]]] = []
        self.outputs: dict[str, bytes] = {}

    def __call__(self, request: Received) -> Reply:
        if request.route == "/v1/files":
            raw = b"Content-Type: " + request.headers["Content-Type"].encode() + b"\r\n\r\n" + request.body
            parts = {p.get_param("name", header="content-disposition"): p
                     for p in BytesParser(policy=email_policy).parsebytes(raw).iter_parts()}
            rows = [json.loads(x) for x in parts["file"].get_payload(decode=True).decode().splitlines()]
            self.inputs.append(rows)
            return Reply(200, {"id": f"file-in{len(self.inputs)}", "object": "file", "purpose": "batch"})
        if request.route == "/v1/batches":
            n = len(self.inputs)
            lines = []
            for row in self.inputs[-1]:
                user = row["body"]["messages"][-1]["content"]
                match = re.search(r'^(Verb|Object): "([^"]+)"$', user, re.MULTILINE)
                assert match, user
                prompt = "verb_properties" if match[1] == "Verb" else "object_properties"
                subject = match[2]
                body = {"choices": [{"index": 0, "finish_reason": "stop", "message": {
                    "role": "assistant", "content": json.dumps(self.answers[(prompt, subject)])}}]}
                lines.append(json.dumps({"custom_id": row["custom_id"], "error": None,
                                         "response": {"status_code": 200, "body": body}}))
            self.outputs[f"file-out{n}"] = ("\n".join(lines) + "\n").encode()
            return Reply(200, _batch_object("validating", id=f"batch_{n}"))
        if request.route.startswith("/v1/batches/batch_"):
            n = request.route.rsplit("_", 1)[-1]
            return Reply(200, _batch_object("completed", id=f"batch_{n}", output_file_id=f"file-out{n}"))
        if request.route.startswith("/v1/files/file-out"):
            return Reply(200, self.outputs[request.route.split("/")[3]])
        return Reply(404, {"error": {"message": f"not served: {request.route}"}})


def test_cli_batch_build_replays_identically(
    tmp_path: Path, clone_cache: Callable[[Path], Path]
) -> None:
    cache = clone_cache(tmp_path / "cache")  # warm embeddings; its records are another provider's
    service = BatchService()
    common = ["--verbs", str(KB_SMALL / "verbs.txt"), "--objects", str(KB_SMALL / "objects.txt"),
              "--prompts", "v1", "--cache", str(cache), "--name", "batch-kb", "--quiet"]
    env = {"COLUMNS": "2000", "OPENAI_API_KEY": ""}
    with FakeServer(responder=service) as server:
        result = CliRunner().invoke(app, ["build", *common, "--provider", "openai-batch",
                                          "--base-url", server.url + "/v1", "--model", "gpt-test",
                                          "--out", str(tmp_path / "batch")], env=env)
    assert result.exit_code == 0, result.output
    assert [len(rows) for rows in service.inputs] == [3, 4]  # one batch per stage: verbs, objects
    replay = CliRunner().invoke(app, ["build", *common, "--record-provider", "openai", "--model",
                                      "gpt-test", "--out", str(tmp_path / "replay")], env=env)
    assert replay.exit_code == 0, replay.output
    a = json.loads((tmp_path / "batch" / "manifest.json").read_text())
    b = json.loads((tmp_path / "replay" / "manifest.json").read_text())
    assert a["content_sha256"] == b["content_sha256"]
    assert {s["provider"] for s in a["sources"]} == {"openai"}
