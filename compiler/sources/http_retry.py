"""HTTP plumbing shared by the live sources: one client factory, one error mapping, Retry-After.

Every live source (LLM transports, the ConceptNet REST client) must classify failures the same
way, because the retry loops above them only look at the exception type: ``TransportError`` is
worth retrying (timeouts, refused or cut connections, 408/429/5xx, a body that is not the JSON
the wire format promises), ``FatalTransportError`` is not (401/403/404/400: retrying cannot fix
a missing key or a wrong model id). Secrets (API keys) are scrubbed from every message, since
error texts end up in terminals, CI logs and ``report.json``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from email.utils import parsedate_to_datetime
from typing import Any, TypeVar

import httpx

from .llm import FatalTransportError, TransportError

#: Seconds; a read timeout is generous because a model may think for a while before answering.
CONNECT_TIMEOUT_S = 10.0
READ_TIMEOUT_S = 120.0
#: Upper bound on a server's Retry-After hint: a longer wait is not worth blocking a build for.
MAX_RETRY_AFTER_S = 60.0
RETRYABLE_STATUS = frozenset({408, 425, 429})
_SNIPPET = 300
T = TypeVar("T")


def make_client(timeout_s: float | None = None, headers: Mapping[str, str] | None = None) -> httpx.Client:
    """An ``httpx.Client`` with explicit timeouts (httpx's default of 5 s is too short for LLMs).

    ``timeout_s`` bounds every phase (connect, read, write, pool); by default connecting gets
    ``CONNECT_TIMEOUT_S`` and reading ``READ_TIMEOUT_S``.
    """
    if timeout_s is None:
        timeout = httpx.Timeout(READ_TIMEOUT_S, connect=CONNECT_TIMEOUT_S)
    else:
        timeout = httpx.Timeout(timeout_s)
    return httpx.Client(timeout=timeout, headers=dict(headers or {}), follow_redirects=False)


def scrub(text: str, secrets: Sequence[str]) -> str:
    """``text`` with every non-empty secret replaced, so keys never reach logs or errors."""
    for secret in secrets:
        if secret:
            text = text.replace(secret, "***")
    return text


def parse_retry_after(value: str | None, now: datetime | None = None) -> float | None:
    """Seconds to wait from a Retry-After header (delta-seconds or HTTP-date), clamped to bounds.

    Unparseable values give None (the caller's own backoff applies); negative or past dates
    give 0; anything above ``MAX_RETRY_AFTER_S`` is capped.
    """
    if value is None or not value.strip():
        return None
    text = value.strip()
    try:
        seconds = float(text)
    except ValueError:
        try:
            when = parsedate_to_datetime(text)
        except (TypeError, ValueError, IndexError):
            return None
        if when.tzinfo is None:
            when = when.replace(tzinfo=UTC)
        seconds = (when - (now or datetime.now(UTC))).total_seconds()
    if seconds != seconds:  # NaN
        return None
    return min(max(seconds, 0.0), MAX_RETRY_AFTER_S)


def error_detail(response: httpx.Response) -> str:
    """The server's own error message (OpenAI and Gemini both use ``{"error": {"message"}}``)."""
    try:
        body = response.json()
    except (ValueError, UnicodeDecodeError):
        return response.text[:_SNIPPET].strip()
    if isinstance(body, dict):
        error = body.get("error")
        if isinstance(error, dict) and isinstance(error.get("message"), str):
            return str(error["message"])[:_SNIPPET]
        if isinstance(error, str):
            return error[:_SNIPPET]
    return json.dumps(body)[:_SNIPPET]


def _status_hint(status: int, key_env: str | None) -> str:
    if status == 401:
        return f"set {key_env} to a valid API key" if key_env else "the server wants credentials"
    if status == 403:
        return "the key is not allowed to use this model or endpoint; check the project and model"
    if status == 404:
        return "check --base-url and --model (the endpoint or model does not exist)"
    return "the server rejected the request; retrying will not help"


def check_status(
    response: httpx.Response, what: str, *, key_env: str | None = None, secrets: Sequence[str] = ()
) -> None:
    """Raise the right transport error for a non-2xx response; return quietly on success."""
    status = response.status_code
    if 200 <= status < 300:
        return
    detail = scrub(error_detail(response), secrets)
    if status in RETRYABLE_STATUS or status >= 500:
        raise TransportError(
            f"{what}: HTTP {status}: {detail}",
            retry_after=parse_retry_after(response.headers.get("retry-after")),
        )
    raise FatalTransportError(f"{what}: HTTP {status}: {detail} ({_status_hint(status, key_env)})")


def send(
    client: httpx.Client,
    method: str,
    url: str,
    *,
    what: str,
    json_body: Any = None,
    params: Mapping[str, str] | None = None,
    headers: Mapping[str, str] | None = None,
    key_env: str | None = None,
    secrets: Sequence[str] = (),
    content: bytes | None = None,
    files: Mapping[str, tuple[str, bytes, str]] | None = None,
    data: Mapping[str, str] | None = None,
) -> httpx.Response:
    """One request with failures mapped to ``TransportError`` / ``FatalTransportError``.

    The body is read completely here, so a connection cut mid-body surfaces as a retryable
    error instead of a half-parsed answer. ``content`` sends raw bytes; ``files`` + ``data``
    a multipart form (file uploads of the batch APIs).
    """
    try:
        response = client.request(
            method, url, json=json_body, params=params, headers=headers, content=content,
            files=files, data=data,
        )
    except httpx.UnsupportedProtocol as exc:
        raise FatalTransportError(f"{what}: unsupported URL {url!r}: {exc}") from None
    except httpx.TimeoutException as exc:
        raise TransportError(f"{what}: timed out ({type(exc).__name__})") from None
    except httpx.RequestError as exc:
        message = scrub(str(exc) or type(exc).__name__, secrets)
        raise TransportError(f"{what}: connection failed ({type(exc).__name__}: {message})") from None
    check_status(response, what, key_env=key_env, secrets=secrets)
    return response


def response_json(response: httpx.Response, what: str) -> Any:
    """The response body as JSON; a body that is not JSON is a (retryable) transport error."""
    try:
        return response.json()
    except (ValueError, UnicodeDecodeError) as exc:
        raise TransportError(
            f"{what}: response body is not JSON ({exc}): {response.text[:120]!r}"
        ) from None


def with_retries(
    call: Callable[[], T],
    *,
    what: str,
    attempts: int = 4,
    backoff_s: float = 0.5,
    sleep: Callable[[float], None] | None = None,
) -> T:
    """Run ``call`` until it succeeds, retrying ``TransportError`` with exponential backoff.

    Used by sources that have no retry loop of their own (ConceptNet); ``LLMSource`` retries
    itself because it also retries invalid payloads. Fatal errors propagate at once; after
    ``attempts`` failures the last error is raised with every attempt listed.
    """
    failures: list[str] = []
    for attempt in range(1, attempts + 1):
        try:
            return call()
        except TransportError as exc:
            failures.append(f"attempt {attempt}: {exc}")
            if attempt == attempts:
                break
            delay = backoff_s * 2 ** (attempt - 1)
            if exc.retry_after is not None:
                delay = max(delay, exc.retry_after)
            (sleep or time.sleep)(delay)
    raise TransportError(f"{what}: gave up after {attempts} attempts: " + "; ".join(failures))
