"""``LLMSource``: cache-first structured prompting with pluggable transports.

The source renders a prompt, computes the record key and looks in the cache. On a miss the
``replay`` provider (the default, no transport) fails and names the missing record and how to
record it; live providers (``openai``, ``gemini``) call their transport, validate the JSON
payload with pydantic, retry on transport errors and invalid payloads, then store the record.
Nothing invalid is ever written to the cache.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Protocol

from pydantic import ValidationError

from ...paths import artifacts_hint
from ...schemas.v1.records import Record, RecordRequest
from ..cache import RecordCache, check_payload, extract_json
from ..prompts import PromptTemplate

LLM_SOURCE = "llm"


class SourceError(RuntimeError):
    """A source could not produce a valid answer (after retries, where they apply)."""


class MissingRecordError(SourceError):
    """Replay found no record for a request; the message names it and how to record it."""


class TransportError(SourceError):
    """The transport failed in a way worth retrying (timeouts, 429, 5xx, cut connections).

    ``retry_after`` carries a server's bounded Retry-After hint (seconds), so the retry loop
    waits at least that long instead of hammering a rate-limited endpoint.
    """

    def __init__(self, message: str, retry_after: float | None = None) -> None:
        super().__init__(message)
        self.retry_after = retry_after


class FatalTransportError(SourceError):
    """The transport failed in a way retrying cannot fix (401, 404, bad request)."""


class Transport(Protocol):
    """Sends one rendered request to a live model and returns the model's text answer."""

    provider: str
    model: str

    def complete(self, request: RecordRequest) -> str: ...


@dataclass(frozen=True)
class PromptCall:
    """One prompt to answer: template + subject (verb/object) + template variables."""

    template: PromptTemplate
    subject: str
    variables: dict[str, Any]


class RateGate:
    """A shared pause for every worker of one source, set by a server's 429 Retry-After.

    When one worker is told to wait, the others must not keep hitting the rate-limited
    endpoint: ``hold`` moves the shared resume time forward (never back), and ``wait`` makes
    every *other* worker sleep until then before its next call. The worker that received the
    429 already waits in its own backoff (at least the Retry-After), so it skips the gate; with
    one worker the gate therefore changes nothing.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._resume_at = 0.0
        self._owner: int | None = None

    def hold(self, seconds: float) -> None:
        with self._lock:
            until = self._clock() + seconds
            if until > self._resume_at:
                self._resume_at = until
                self._owner = threading.get_ident()

    def wait(self, sleep: Callable[[float], None]) -> float:
        """Sleep until the shared resume time (unless this thread set it); returns the wait."""
        with self._lock:
            if self._owner == threading.get_ident():
                return 0.0
            remaining = self._resume_at - self._clock()
        if remaining <= 0:
            return 0.0
        sleep(remaining)
        return remaining


@dataclass
class LLMSource:
    """Answers prompts from the record cache, and from a live transport when one is given.

    ``provider``/``model`` name who produced the answers (part of every key): ``curated`` for
    the project's hand-written records, ``openai``/``gemini`` (or a self-hosted server's id) for
    live models.
    """

    cache: RecordCache
    provider: str = "curated"
    model: str = "craft-e-curators"
    transport: Transport | None = None
    params: dict[str, Any] = field(default_factory=lambda: {"temperature": 0.0})
    max_attempts: int = 4
    max_concurrency: int = 4
    backoff_s: float = 0.5
    sleep: Callable[[float], None] | None = None
    gate: RateGate = field(default_factory=RateGate, repr=False, compare=False)

    def request_for(self, call: PromptCall) -> RecordRequest:
        return RecordRequest(
            provider=self.provider,
            model=self.model,
            prompt=call.template.ref,
            messages=call.template.render(**call.variables),
            params=dict(self.params),
            response_schema=call.template.response_schema(),
            subject=call.subject,
            variables=call.variables,
        )

    def lookup(self, call: PromptCall) -> Record | None:
        request = self.request_for(call)
        record = self.cache.get(LLM_SOURCE, request.key())
        return None if record is None else check_payload(record, call.template)

    def fetch(self, call: PromptCall) -> Record:
        """The record answering ``call``: from the cache, else from the live transport."""
        request = self.request_for(call)
        key = request.key()
        cached = self.cache.get(LLM_SOURCE, key)
        if cached is not None:
            return check_payload(cached, call.template)
        if self.transport is None:
            raise MissingRecordError(
                f"no record for {call.template.ref} subject={call.subject!r} "
                f"(provider={self.provider}, model={self.model}); expected "
                f"{self.cache.path_for(LLM_SOURCE, key)}. Record it with a live provider "
                f"(craftc build --provider openai|gemini ...) or write an answer and store it "
                f"with `craftc curate`.{artifacts_hint(self.cache.path_for(LLM_SOURCE, key))}"
            )
        return self._ask(call, request, key)

    def fetch_many(
        self, calls: Sequence[PromptCall], on_done: Callable[[PromptCall], None] | None = None
    ) -> list[Record]:
        """Fetch in input order with bounded concurrency (live calls overlap, order kept)."""

        def one(call: PromptCall) -> Record:
            record = self.fetch(call)
            if on_done is not None:
                on_done(call)
            return record

        if self.transport is None or self.max_concurrency <= 1:
            return [one(c) for c in calls]
        with ThreadPoolExecutor(max_workers=self.max_concurrency) as pool:
            return list(pool.map(one, calls))

    def _ask(self, call: PromptCall, request: RecordRequest, key: str) -> Record:
        assert self.transport is not None
        model = call.template.payload_model
        failures: list[str] = []
        for attempt in range(1, self.max_attempts + 1):
            self.gate.wait(self.sleep or time.sleep)  # another worker was told to back off
            try:
                raw = self.transport.complete(request)
            except FatalTransportError:
                raise
            except TransportError as exc:
                failures.append(f"attempt {attempt}: {exc}")
                if exc.retry_after is not None:
                    self.gate.hold(exc.retry_after)
                self._backoff(attempt, exc.retry_after)
                continue
            try:
                payload = model.model_validate(extract_json(raw))
            except (ValueError, ValidationError) as exc:
                failures.append(f"attempt {attempt}: invalid payload: {str(exc)[:200]}")
                self._backoff(attempt)
                continue
            record = Record(
                key=key,
                source=LLM_SOURCE,
                request=request,
                raw_response=raw,
                payload=payload.model_dump(mode="json"),
                note=f"recorded via {self.transport.provider} transport",
            )
            self.cache.put(record)
            return record
        raise SourceError(
            f"{self.provider}/{self.model} gave no valid answer for {call.template.ref} "
            f"subject={call.subject!r} after {self.max_attempts} attempts: " + "; ".join(failures)
        )

    def _backoff(self, attempt: int, retry_after: float | None = None) -> None:
        if attempt >= self.max_attempts:
            return
        delay = self.backoff_s * 2 ** (attempt - 1)
        if retry_after is not None:
            delay = max(delay, retry_after)
        (self.sleep or time.sleep)(delay)
