"""Batch providers: every missing record of a build stage as ONE asynchronous batch job.

``craftc build --provider openai-batch`` / ``gemini-batch`` answer the same prompts as the
synchronous ``openai`` / ``gemini`` providers, through the providers' batch APIs (about half the
price, no per-minute rate limits, results within 24 h):

* **OpenAI Batch API.** A JSONL input file, one line per request:
  ``{"custom_id", "method": "POST", "url": "/v1/chat/completions", "body": <chat body>}``,
  uploaded with ``POST /v1/files`` (multipart, ``purpose=batch``); ``POST /v1/batches``
  (``input_file_id``, ``endpoint``, ``completion_window: 24h``); ``GET /v1/batches/{id}`` until
  ``completed`` / ``failed`` / ``expired`` / ``cancelled``; then the JSONL contents of
  ``output_file_id`` and ``error_file_id`` from ``GET /v1/files/{id}/content``, one
  ``{"custom_id", "response": {"status_code", "body"}, "error"}`` line per request.
* **Gemini Batch Mode.** ``POST /models/{model}:batchGenerateContent`` with the requests inlined
  (``input_config.requests.requests[] = {"request", "metadata": {"key"}}``) while they fit in
  the documented 20 MB, otherwise as a JSONL file of ``{"key", "request"}`` lines uploaded with
  the resumable Files API (``input_config.file_name``); the returned operation ``batches/{id}``
  is polled with ``GET /batches/{id}`` until its state is SUCCEEDED / FAILED / CANCELLED /
  EXPIRED; answers come inlined (``response.inlinedResponses.inlinedResponses[]``) or as a
  responses file (``response.responsesFile``, downloaded with ``:download?alt=media``).

Each request body is exactly what the synchronous transport sends (``OpenAITransport`` /
``GeminiTransport.request_body``) and each answer is read by the same functions, so a record
made by a batch has the same provider id, model, request and key as one made synchronously,
and a KB recorded in batch replays identically.

The build's stages depend on each other (stage 2 names the properties stage 1 found), so a
build submits one batch per stage that has missing records. While a batch runs, its id and the
``custom_id -> record key`` map live in ``<cache>/batches/<name>.json`` (written atomically);
after a crash or Ctrl-C the same command finds that file and resumes polling the same batch
instead of paying for a new one. Items that failed are named by prompt and subject, the
others are stored, and re-running the command asks only for the failed ones.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import urlsplit

import httpx
from pydantic import ValidationError

from ...files import atomic_write_bytes
from ...schemas.v1.records import Record, RecordRequest
from ..cache import CacheError, check_payload, extract_json
from .http_retry import response_json, send, with_retries
from .llm import (
    LLM_SOURCE,
    LLMSource,
    PromptCall,
    SourceError,
    TransportError,
)
from .transports import (
    GEMINI_BASE_URL,
    GEMINI_KEY_ENV,
    GEMINI_MODEL,
    OPENAI_BASE_URL,
    OPENAI_KEY_ENV,
    OPENAI_MODEL,
    GeminiTransport,
    OpenAITransport,
    _HTTPTransport,
    gemini_answer_text,
    openai_answer_text,
)

BATCH_PROVIDERS = ("openai-batch", "gemini-batch")
#: Folder under the cache root holding the state of batches in flight (no records).
BATCH_STATE_DIR = "batches"
#: OpenAI: at most 50,000 requests per batch (and a 200 MB input file).
OPENAI_MAX_REQUESTS = 50_000
OPENAI_ENDPOINT = "/v1/chat/completions"
#: Gemini: inline requests while the whole request stays under 20 MB, a JSONL file beyond.
GEMINI_INLINE_LIMIT_BYTES = 19 * 1024 * 1024
_FAILED_SHOWN = 20


class BatchFailedError(SourceError):
    """Some items of a batch got no valid answer; ``failed`` maps subject labels to reasons."""

    def __init__(self, message: str, failed: Mapping[str, str]) -> None:
        super().__init__(message)
        self.failed = dict(failed)


@dataclass(frozen=True)
class BatchItem:
    """One request of a batch: its ``custom_id`` (key in Gemini) and the record it will fill."""

    custom_id: str
    request: RecordRequest

    @property
    def key(self) -> str:
        return self.request.key()

    @property
    def label(self) -> str:
        return f"{self.request.prompt} subject={self.request.subject!r}"


@dataclass
class BatchStatus:
    """What a poll said: the provider's state word, whether it is final, and the raw object."""

    state: str
    done: bool
    data: dict[str, Any]
    counts: str = ""


@dataclass
class BatchResults:
    """Answer texts and per-item failures by ``custom_id``; ``batch_error`` fails them all."""

    texts: dict[str, str] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)
    batch_error: str = ""


class BatchBackend(Protocol):
    """One provider's batch API. ``provider``/``model`` are the synchronous provider's ids."""

    name: str
    provider: str
    model: str

    def submit(self, items: Sequence[BatchItem]) -> dict[str, str]:
        """Create the batch; returns at least ``{"batch_id": ...}`` (plus file ids)."""
        ...

    def poll(self, batch_id: str) -> BatchStatus: ...

    def results(self, status: BatchStatus) -> BatchResults: ...


# --------------------------------------------------------------------------- HTTP backends


class _HTTPBatch(_HTTPTransport):
    """What both batch APIs share: the synchronous transports' base URL, model, pooled client
    and key scrubbing, plus retried HTTP calls."""

    name: str

    def __init__(
        self,
        model: str,
        base_url: str,
        api_key: str | None,
        *,
        timeout_s: float | None = None,
        client: httpx.Client | None = None,
        attempts: int = 4,
        sleep: Callable[[float], None] | None = None,
    ) -> None:
        super().__init__(model, base_url, api_key, timeout_s=timeout_s, client=client)
        self._attempts = attempts
        self._sleep = sleep

    def _call(self, method: str, url: str, what: str, **kwargs: Any) -> httpx.Response:
        """One HTTP call, retried on transient failures (429 Retry-After honoured)."""
        return with_retries(
            lambda: send(self._client, method, url, what=what, key_env=self.key_env,
                         secrets=self._secrets, **kwargs),
            what=what, attempts=self._attempts, sleep=self._sleep,
        )

    def _json(self, method: str, url: str, what: str, **kwargs: Any) -> dict[str, Any]:
        data = response_json(self._call(method, url, what, **kwargs), what)
        if not isinstance(data, dict):
            raise TransportError(f"{what}: expected a JSON object, got {str(data)[:120]}")
        return data


class OpenAIBatch(_HTTPBatch):
    """The OpenAI Batch API (also served by OpenAI-compatible gateways at ``--base-url``)."""

    name = "openai-batch"
    provider = "openai"
    key_env = OPENAI_KEY_ENV

    def _auth_headers(self, api_key: str | None) -> dict[str, str]:
        return {"Authorization": f"Bearer {api_key}"} if api_key else {}

    def input_jsonl(self, items: Sequence[BatchItem]) -> bytes:
        """The batch input file: one chat-completions request per line, as documented."""
        body_of = OpenAITransport(self.model, self.base_url, None, client=self._client)
        lines = [
            json.dumps(
                {"custom_id": item.custom_id, "method": "POST", "url": OPENAI_ENDPOINT,
                 "body": body_of.request_body(item.request)},
                ensure_ascii=False,
            )
            for item in items
        ]
        return ("\n".join(lines) + "\n").encode()

    def submit(self, items: Sequence[BatchItem]) -> dict[str, str]:
        if len(items) > OPENAI_MAX_REQUESTS:
            raise SourceError(
                f"openai-batch: {len(items)} requests, more than the {OPENAI_MAX_REQUESTS} one "
                "batch may hold; build a smaller vocabulary first (records are reused)"
            )
        upload = self._json(
            "POST", f"{self.base_url}/files", "openai-batch upload input file",
            files={"file": ("craft-e-batch.jsonl", self.input_jsonl(items), "application/jsonl")},
            data={"purpose": "batch"},
        )
        file_id = upload.get("id")
        if not isinstance(file_id, str):
            raise SourceError(f"openai-batch: the file upload returned no id: {str(upload)[:160]}")
        batch = self._json(
            "POST", f"{self.base_url}/batches", "openai-batch create batch",
            json_body={"input_file_id": file_id, "endpoint": OPENAI_ENDPOINT,
                       "completion_window": "24h",
                       "metadata": {"description": "craftc build (CRAFT-E)"}},
        )
        batch_id = batch.get("id")
        if not isinstance(batch_id, str):
            raise SourceError(f"openai-batch: creating the batch returned no id: {str(batch)[:160]}")
        return {"batch_id": batch_id, "input_file_id": file_id}

    def poll(self, batch_id: str) -> BatchStatus:
        data = self._json("GET", f"{self.base_url}/batches/{batch_id}", f"openai-batch poll {batch_id}")
        state = str(data.get("status", "unknown"))
        counts = data.get("request_counts")
        text = ""
        if isinstance(counts, dict):
            text = f"{counts.get('completed', 0)}/{counts.get('total', 0)} done, {counts.get('failed', 0)} failed"
        return BatchStatus(state, state in ("completed", "failed", "expired", "cancelled"), data, text)

    def results(self, status: BatchStatus) -> BatchResults:
        out = BatchResults()
        data = status.data
        if status.state == "failed":
            errors = data.get("errors")
            rows = errors.get("data") if isinstance(errors, dict) else None
            messages = [
                f"{e.get('code')}: {e.get('message')}" + (f" (line {e['line']})" if e.get("line") else "")
                for e in rows or [] if isinstance(e, dict)
            ]
            out.batch_error = "batch failed: " + ("; ".join(messages) or "no reason given")
        for field_name in ("output_file_id", "error_file_id"):
            file_id = data.get(field_name)
            if isinstance(file_id, str) and file_id:
                text = self._call(
                    "GET", f"{self.base_url}/files/{file_id}/content", f"openai-batch {field_name}"
                ).text
                self._read_lines(text, out)
        if status.state in ("expired", "cancelled") and not out.batch_error:
            out.batch_error = f"batch {status.state} before this item was answered"
        return out

    def _read_lines(self, text: str, out: BatchResults) -> None:
        for lineno, line in enumerate(text.splitlines(), start=1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
                custom_id = str(row["custom_id"])
            except (ValueError, KeyError, TypeError):
                raise SourceError(f"openai-batch: result line {lineno} is not a batch result: {line[:120]!r}") from None
            error = row.get("error")
            response = row.get("response")
            what = f"openai-batch {custom_id}"
            if error:
                out.errors[custom_id] = _error_text(error)
            elif not isinstance(response, dict):
                out.errors[custom_id] = "no response"
            elif response.get("status_code") != 200:
                body = response.get("body")
                detail = _error_text(body.get("error")) if isinstance(body, dict) and body.get("error") else str(body)[:160]
                out.errors[custom_id] = f"HTTP {response.get('status_code')}: {detail}"
            else:
                try:
                    out.texts[custom_id] = openai_answer_text(response.get("body"), what)
                except TransportError as exc:
                    out.errors[custom_id] = str(exc)


class GeminiBatch(_HTTPBatch):
    """Gemini Batch Mode (``batchGenerateContent``), inlined requests or a JSONL input file."""

    name = "gemini-batch"
    provider = "gemini"
    key_env = GEMINI_KEY_ENV
    inline_limit_bytes = GEMINI_INLINE_LIMIT_BYTES

    def _auth_headers(self, api_key: str | None) -> dict[str, str]:
        return {"x-goog-api-key": api_key} if api_key else {}

    def _split_base(self) -> tuple[str, str]:
        """(origin, version path): uploads go to ``/upload/<version>``, downloads ``/download``."""
        parts = urlsplit(self.base_url)
        return f"{parts.scheme}://{parts.netloc}", parts.path.rstrip("/")

    def request_bodies(self, items: Sequence[BatchItem]) -> list[dict[str, Any]]:
        body_of = GeminiTransport(self.model, self.base_url, None, client=self._client)
        return [body_of.request_body(item.request) for item in items]

    def input_jsonl(self, items: Sequence[BatchItem]) -> bytes:
        """The JSONL input file: one ``{"key", "request"}`` line per request, as documented."""
        lines = [
            json.dumps({"key": item.custom_id, "request": body}, ensure_ascii=False)
            for item, body in zip(items, self.request_bodies(items), strict=True)
        ]
        return ("\n".join(lines) + "\n").encode()

    def submit(self, items: Sequence[BatchItem]) -> dict[str, str]:
        model = self.model.removeprefix("models/")
        display = "craft-e-" + hashlib.sha256(
            "".join(i.key for i in items).encode()
        ).hexdigest()[:12]
        inlined = [
            {"request": body, "metadata": {"key": item.custom_id}}
            for item, body in zip(items, self.request_bodies(items), strict=True)
        ]
        size = len(json.dumps(inlined).encode())
        state: dict[str, str] = {}
        if size <= self.inline_limit_bytes:
            input_config: dict[str, Any] = {"requests": {"requests": inlined}}
        else:
            file_name = self._upload(self.input_jsonl(items), display)
            input_config = {"file_name": file_name}
            state["input_file"] = file_name
        op = self._json(
            "POST", f"{self.base_url}/models/{model}:batchGenerateContent",
            "gemini-batch create batch",
            json_body={"batch": {"display_name": display, "input_config": input_config}},
        )
        name = op.get("name")
        if not isinstance(name, str) or not name:
            raise SourceError(f"gemini-batch: creating the batch returned no name: {str(op)[:160]}")
        return {"batch_id": name, **state}

    def _upload(self, data: bytes, display: str) -> str:
        """The resumable Files API upload (start, then upload+finalize); returns ``files/...``."""
        origin, version = self._split_base()
        start = self._call(
            "POST", f"{origin}/upload{version}/files", "gemini-batch start upload",
            headers={"X-Goog-Upload-Protocol": "resumable", "X-Goog-Upload-Command": "start",
                     "X-Goog-Upload-Header-Content-Length": str(len(data)),
                     "X-Goog-Upload-Header-Content-Type": "application/jsonl"},
            json_body={"file": {"display_name": display}},
        )
        upload_url = start.headers.get("x-goog-upload-url")
        if not upload_url:
            raise SourceError("gemini-batch: the upload start returned no X-Goog-Upload-URL")
        done = response_json(self._call(
            "POST", upload_url, "gemini-batch upload input file", content=data,
            headers={"X-Goog-Upload-Offset": "0", "X-Goog-Upload-Command": "upload, finalize"},
        ), "gemini-batch upload input file")
        info = done.get("file") if isinstance(done, dict) else None
        name = info.get("name") if isinstance(info, dict) else None
        if not isinstance(name, str):
            raise SourceError(f"gemini-batch: the upload returned no file name: {str(done)[:160]}")
        return name

    def poll(self, batch_id: str) -> BatchStatus:
        data = self._json("GET", f"{self.base_url}/{batch_id}", f"gemini-batch poll {batch_id}")
        meta = data.get("metadata") if isinstance(data.get("metadata"), dict) else {}
        assert isinstance(meta, dict)
        raw_state = str(meta.get("state", "unknown"))
        # REST spells BATCH_STATE_*, the SDKs JOB_STATE_*: compare the part after STATE_
        state = raw_state.rsplit("STATE_", 1)[-1]
        stats = meta.get("batchStats")
        counts = ""
        if isinstance(stats, dict):
            counts = (f"{stats.get('successfulRequestCount', 0)}/{stats.get('requestCount', 0)} "
                      f"done, {stats.get('failedRequestCount', 0)} failed")
        done = bool(data.get("done")) or state in ("SUCCEEDED", "FAILED", "CANCELLED", "EXPIRED")
        return BatchStatus(raw_state, done, data, counts)

    def results(self, status: BatchStatus) -> BatchResults:
        out = BatchResults()
        data = status.data
        error = data.get("error")
        if error:
            out.batch_error = "batch failed: " + _error_text(error)
        response = data.get("response")
        if isinstance(response, dict):
            inlined = response.get("inlinedResponses")
            if isinstance(inlined, dict):
                inlined = inlined.get("inlinedResponses")
            if isinstance(inlined, list):
                for position, row in enumerate(inlined):
                    if isinstance(row, dict):
                        meta = row.get("metadata")
                        key = meta.get("key") if isinstance(meta, dict) else None
                        self._read_row(str(key) if key is not None else _position_id(position), row, out)
            file_name = response.get("responsesFile")
            if isinstance(file_name, str) and file_name:
                origin, version = self._split_base()
                text = self._call(
                    "GET", f"{origin}/download{version}/{file_name}:download",
                    "gemini-batch download responses", params={"alt": "media"},
                ).text
                for lineno, line in enumerate(text.splitlines(), start=1):
                    if not line.strip():
                        continue
                    try:
                        row = json.loads(line)
                        key = str(row["key"])
                    except (ValueError, KeyError, TypeError):
                        raise SourceError(
                            f"gemini-batch: responses line {lineno} is not a batch result: {line[:120]!r}"
                        ) from None
                    self._read_row(key, row, out)
        if status.done and not out.batch_error and not out.texts and not out.errors:
            out.batch_error = f"batch ended {status.state} without responses"
        elif status.state.endswith(("EXPIRED", "CANCELLED")) and not out.batch_error:
            out.batch_error = f"batch {status.state} before this item was answered"
        return out

    @staticmethod
    def _read_row(key: str, row: Mapping[str, Any], out: BatchResults) -> None:
        if row.get("error"):
            out.errors[key] = _error_text(row["error"])
            return
        try:
            out.texts[key] = gemini_answer_text(row.get("response"), f"gemini-batch {key}")
        except TransportError as exc:
            out.errors[key] = str(exc)


def _position_id(position: int) -> str:
    return custom_id_for(position)


def custom_id_for(position: int) -> str:
    """The custom_id (Gemini: key) of the request at ``position`` in a batch."""
    return f"req-{position:06d}"


def _error_text(error: Any) -> str:
    if isinstance(error, dict):
        code = error.get("status") or error.get("code") or error.get("type")
        message = error.get("message") or json.dumps(error)[:160]
        return f"{code}: {message}" if code else str(message)
    return str(error)[:200]


def make_batch_backend(
    provider: str,
    model: str | None = None,
    base_url: str | None = None,
    *,
    timeout_s: float | None = None,
    env: Mapping[str, str] | None = None,
) -> OpenAIBatch | GeminiBatch:
    """The batch backend for ``openai-batch`` / ``gemini-batch``, its key from the environment."""
    environ = os.environ if env is None else env
    if provider == "openai-batch":
        key = environ.get(OPENAI_KEY_ENV) or None
        _require_key(provider, key, base_url, OPENAI_KEY_ENV)
        return OpenAIBatch(model or OPENAI_MODEL, base_url or OPENAI_BASE_URL, key, timeout_s=timeout_s)
    if provider == "gemini-batch":
        key = environ.get(GEMINI_KEY_ENV) or None
        _require_key(provider, key, base_url, GEMINI_KEY_ENV)
        return GeminiBatch(model or GEMINI_MODEL, base_url or GEMINI_BASE_URL, key, timeout_s=timeout_s)
    raise ValueError(f"unknown batch provider {provider!r}; choose one of {', '.join(BATCH_PROVIDERS)}")


def _require_key(provider: str, key: str | None, base_url: str | None, key_env: str) -> None:
    if key is None and base_url is None:
        raise ValueError(
            f"{provider}: {key_env} is not set; export {key_env}=<your key>, or pass --base-url "
            "for a server that needs no key"
        )


# --------------------------------------------------------------------------- state + source


def state_dir(cache_root: Path) -> Path:
    return cache_root / BATCH_STATE_DIR


def _state_name(backend: BatchBackend, keys: Sequence[str]) -> str:
    digest = hashlib.sha256("\n".join(sorted(keys)).encode()).hexdigest()[:16]
    return f"{backend.name}-{digest}.json"


def write_state(path: Path, state: Mapping[str, Any]) -> None:
    atomic_write_bytes(path, (json.dumps(state, indent=1, sort_keys=True) + "\n").encode())


def read_state(path: Path) -> dict[str, Any]:
    try:
        state = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise CacheError(f"{path}: unreadable batch state ({exc}); delete it to start over") from None
    if not isinstance(state, dict) or not isinstance(state.get("batch_id"), str) \
            or not isinstance(state.get("items"), dict):
        raise CacheError(f"{path}: not a batch state file; delete it to start over")
    return state


@dataclass
class BatchLLMSource(LLMSource):
    """An ``LLMSource`` whose misses are answered by one batch per ``fetch_many`` call.

    ``provider``/``model`` must be the backend's synchronous ids (``openai``/``gemini``), so
    keys are the synchronous provider's. Polls back off from ``poll_s`` by ``poll_factor`` up
    to ``max_poll_s``; ``max_wait_s`` bounds one command's wait (the batch keeps running and
    the next command resumes it).
    """

    backend: BatchBackend | None = None
    poll_s: float = 10.0
    poll_factor: float = 1.5
    max_poll_s: float = 300.0
    max_wait_s: float | None = None
    log: Callable[[str], None] | None = None

    def fetch(self, call: PromptCall) -> Record:
        return self.fetch_many([call])[0]

    def fetch_many(
        self, calls: Sequence[PromptCall], on_done: Callable[[PromptCall], None] | None = None
    ) -> list[Record]:
        if self.backend is None:
            raise SourceError("BatchLLMSource needs a batch backend")
        requests = [self.request_for(c) for c in calls]
        templates = {r.key(): c.template for r, c in zip(requests, calls, strict=True)}
        missing: dict[str, RecordRequest] = {}
        for request in requests:
            key = request.key()
            if key not in missing and self.cache.get(LLM_SOURCE, key) is None:
                missing[key] = request
        failed: dict[str, str] = {}  # key -> reason
        if missing:
            self._answer(missing, templates, failed)
        records: list[Record] = []
        reasons: dict[str, str] = {}
        for call, request in zip(calls, requests, strict=True):
            key = request.key()
            cached = self.cache.get(LLM_SOURCE, key)
            if cached is None:
                reasons[f"{request.prompt} subject={call.subject!r}"] = failed.get(key, "no answer")
                continue
            records.append(check_payload(cached, call.template))
            if on_done is not None:
                on_done(call)
        if reasons:
            shown = [f"  {label}: {why}" for label, why in sorted(reasons.items())[:_FAILED_SHOWN]]
            more = len(reasons) - len(shown)
            raise BatchFailedError(
                f"{self.backend.name}: {len(reasons)} of {len(calls)} requests got no valid "
                "answer:\n" + "\n".join(shown) + (f"\n  ... and {more} more" if more > 0 else "")
                + "\nThe answered ones are recorded; run the same command again to submit only "
                "the failed ones.",
                reasons,
            )
        return records

    # -- one stage's misses ---------------------------------------------------------------

    def _answer(
        self,
        missing: dict[str, RecordRequest],
        templates: Mapping[str, Any],
        failed: dict[str, str],
    ) -> None:
        assert self.backend is not None
        folder = state_dir(self.cache.root)
        # 1. resume batches a crashed or interrupted command left behind
        for path in sorted(folder.glob(f"{self.backend.name}-*.json")):
            left = read_state(path)
            if left.get("model") != self.model or not set(left["items"].values()) & set(missing):
                continue
            self._say(f"{self.backend.name}: resuming batch {left['batch_id']} ({path.name})")
            self._finish(path, left, missing, templates, failed)
        todo = [r for k, r in missing.items() if k not in failed and self.cache.get(LLM_SOURCE, k) is None]
        if not todo:
            return
        # 2. one new batch for the rest
        items = [BatchItem(custom_id_for(i), r) for i, r in enumerate(todo)]
        path = folder / _state_name(self.backend, [i.key for i in items])
        submitted = self.backend.submit(items)
        state: dict[str, Any] = {
            **submitted,
            "backend": self.backend.name,
            "provider": self.provider,
            "model": self.model,
            "submitted_at": datetime.now(UTC).isoformat(timespec="seconds"),
            "items": {i.custom_id: i.key for i in items},
            "subjects": {i.custom_id: i.label for i in items},
        }
        write_state(path, state)
        self._say(f"{self.backend.name}: submitted batch {state['batch_id']} with {len(items)} "
                  f"requests (state {path}; an interrupted build resumes it)")
        self._finish(path, state, missing, templates, failed)

    def _finish(
        self,
        path: Path,
        state: Mapping[str, Any],
        missing: Mapping[str, RecordRequest],
        templates: Mapping[str, Any],
        failed: dict[str, str],
    ) -> None:
        """Poll ``state``'s batch to its end, store every valid answer, then drop the state."""
        assert self.backend is not None
        batch_id = str(state["batch_id"])
        status = self._wait(batch_id, path)
        results = self.backend.results(status)
        stored = 0
        for custom_id, key in state["items"].items():
            request = missing.get(key)
            if request is None or self.cache.get(LLM_SOURCE, key) is not None:
                continue  # not asked by this build stage, or already answered
            text = results.texts.get(custom_id)
            if text is None:
                failed[key] = results.errors.get(custom_id) or results.batch_error or "missing from the batch results"
                continue
            try:
                payload = templates[key].payload_model.model_validate(extract_json(text))
            except (ValueError, ValidationError) as exc:
                failed[key] = f"invalid payload: {str(exc)[:200]}"
                continue
            self.cache.put(Record(
                key=key, source=LLM_SOURCE, request=request, raw_response=text,
                payload=payload.model_dump(mode="json"),
                note=f"recorded via {self.backend.name} ({batch_id})",
            ))
            stored += 1
        self._say(f"{self.backend.name}: batch {batch_id} {status.state}: {stored} records stored, "
                  f"{sum(1 for k in state['items'].values() if k in failed)} failed")
        path.unlink(missing_ok=True)

    def _wait(self, batch_id: str, path: Path) -> BatchStatus:
        assert self.backend is not None
        sleep = self.sleep or time.sleep
        delay, waited = self.poll_s, 0.0
        while True:
            status = self.backend.poll(batch_id)
            if status.done:
                return status
            self._say(f"{self.backend.name}: batch {batch_id} {status.state}"
                      + (f" ({status.counts})" if status.counts else ""))
            if self.max_wait_s is not None and waited + delay > self.max_wait_s:
                raise SourceError(
                    f"{self.backend.name}: batch {batch_id} still {status.state} after "
                    f"{waited:.0f} s (--batch-wait); it keeps running: run the same command "
                    f"again to resume it (state in {path})"
                )
            sleep(delay)
            waited += delay
            delay = min(delay * self.poll_factor, self.max_poll_s)

    def _say(self, message: str) -> None:
        if self.log is not None:
            self.log(message)


__all__ = [
    "BATCH_PROVIDERS",
    "BatchFailedError",
    "BatchItem",
    "BatchLLMSource",
    "GeminiBatch",
    "OpenAIBatch",
    "make_batch_backend",
]
