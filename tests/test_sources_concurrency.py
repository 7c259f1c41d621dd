"""Synchronous providers under load: bounded concurrency, a 429 pauses every worker, --timeout.

``LLMSource.fetch_many`` runs up to ``max_concurrency`` live requests at once. When the server
answers one of them with 429 + Retry-After, the other workers must not keep hitting it: they
wait at a shared gate until the hinted time (the worker that got the 429 waits in its own
backoff). ``craftc build --concurrency N --timeout S`` set both.
"""

from __future__ import annotations

import json
import threading
import time
from functools import partial
from pathlib import Path
from typing import Any

import pytest
from servers import FakeServer, Received, Reply, openai_reply
from typer.testing import CliRunner

from craft_e.compiler.cache import RecordCache
from craft_e.compiler.cli import app
from craft_e.compiler.llm_knowledge import verb_call
from craft_e.compiler.sources.llm import LLM_SOURCE, LLMSource, RateGate
from craft_e.compiler.sources.transports import OpenAITransport

KB_SMALL = Path(__file__).resolve().parent / "fixtures" / "kb_small"
VALID = json.dumps({"verb": "x", "properties": [{"name": "sharp edge", "weight": 0.9}]})
VERBS = ["cut", "pour", "dig", "scoop", "stab", "stir", "wipe", "hammer"]


def test_a_429_pauses_every_worker_until_retry_after(tmp_path: Path) -> None:
    arrivals: list[float] = []
    limited_at: list[float] = []
    lock = threading.Lock()
    in_flight = {"now": 0, "max": 0}

    def respond(request: Received) -> Reply:
        now = time.monotonic()
        with lock:
            arrivals.append(now)
            first = len(arrivals) == 1
            in_flight["now"] += 1
            in_flight["max"] = max(in_flight["max"], in_flight["now"])
        try:
            if first:
                limited_at.append(now)
                return Reply(429, {"error": {"message": "rate limited"}}, headers={"Retry-After": "1"})
            time.sleep(0.05)  # a model thinking: keeps several requests in flight
            return openai_reply(VALID)
        finally:
            with lock:
                in_flight["now"] -= 1

    with FakeServer(responder=respond) as server:
        source = LLMSource(RecordCache(tmp_path / "cache"), provider="openai", model="test-model",
                           transport=OpenAITransport("test-model", server.url + "/v1", None),
                           max_concurrency=3, backoff_s=0.01)
        records = source.fetch_many([verb_call(v, version="v1") for v in VERBS])
    assert [r.request.subject for r in records] == VERBS
    assert len(arrivals) == len(VERBS) + 1  # one retry
    assert in_flight["max"] <= 3
    t429 = limited_at[0]
    # requests already in flight when the 429 came arrive at once; after that, nobody calls
    # the server again until the Retry-After has passed
    paused = [t - t429 for t in arrivals if 0.03 < t - t429 < 0.95]
    assert paused == [], paused
    assert max(arrivals) - t429 >= 0.95


def test_rate_gate_spares_the_worker_that_was_limited() -> None:
    clock = [100.0]
    slept: list[float] = []
    gate = RateGate(clock=lambda: clock[0])
    gate.hold(3.0)
    assert gate.wait(slept.append) == 0.0  # this thread set it and waits in its own backoff
    other: list[float] = []
    worker = threading.Thread(target=lambda: other.append(gate.wait(slept.append)))
    worker.start()
    worker.join()
    assert other == [3.0] and slept == [3.0]
    gate.hold(1.0)  # an earlier resume time never shortens the pause
    clock[0] = 102.0
    worker = threading.Thread(target=lambda: other.append(gate.wait(slept.append)))
    worker.start()
    worker.join()
    assert other[-1] == pytest.approx(1.0)


def _build_args(tmp_path: Path, url: str, *extra: str) -> list[str]:
    return ["build", "--verbs", str(KB_SMALL / "verbs.txt"), "--objects", str(KB_SMALL / "objects.txt"),
            "--provider", "openai", "--base-url", url + "/v1", "--model", "test-model",
            "--prompts", "v1", "--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "kb"),
            "--name", "live-kb", "--quiet", *extra]


def test_cli_timeout_and_concurrency_reach_the_source(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    made: list[dict[str, Any]] = []

    def one_attempt(**kwargs: Any) -> LLMSource:
        made.append(kwargs)
        return partial(LLMSource, max_attempts=1, sleep=lambda s: None)(**kwargs)

    monkeypatch.setattr("craft_e.compiler.build.LLMSource", one_attempt)
    with FakeServer(responder=lambda r: Reply(200, b"{}", delay_s=1.0)) as server:
        result = CliRunner().invoke(
            app, _build_args(tmp_path, server.url, "--timeout", "0.3", "--concurrency", "2"),
            env={"COLUMNS": "2000", "OPENAI_API_KEY": ""},
        )
    assert result.exit_code == 3, result.output
    # the client gave up at --timeout: had it waited the server's 1 s, it would have read "{}"
    # and failed on the answer's shape, not with "timed out" (no wall-clock bound needed)
    assert "timed out" in result.output
    assert made and made[0]["max_concurrency"] == 2
    assert not list(RecordCache(tmp_path / "cache").iter_records(LLM_SOURCE))


def test_cli_rejects_zero_concurrency(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, _build_args(tmp_path, "http://127.0.0.1:9", "--concurrency", "0"))
    assert result.exit_code == 2
