"""Fault injection on ``craftc build`` with a live provider: kills, slow and broken LLM servers.

The promises under test (DESIGN.md, "Record cache" and "Emit"):

* **Killed mid-build** (SIGKILL while answers are still arriving): the record cache stays
  consistent — every record file is whole and hashes to its key, ``craftc cache verify`` exits 0
  — and ``--out`` is either absent or still the previous bundle, untouched. Rerunning the build
  completes and asks the server only for what was not recorded yet.
* **Broken server** (timeouts, 429, 500, cut connections, bodies that are not JSON, answers that
  fail the schema): each request is retried a bounded number of times; nothing invalid is ever
  written; a subject that never gets a valid answer fails the build with exit 3 and a message
  naming it, while the answers that did arrive stay recorded for the next run.

Kill timing is made deterministic: the fake server answers the first ``K`` requests (slowly) and
holds every later one open, and the build is killed once ``K`` records exist and a held request
is in flight — so the kill lands while the build waits on the network, never inside a record
write. A kill *inside* a write (a window of microseconds) can leave a same-folder temporary
file; that case is simulated directly: the leftover is reported as **orphaned**, never corrupt,
and is ignored by builds (see docs/robustness.md). So is a kill *inside* the bundle swap, the one
moment ``--out`` is briefly absent: the previous bundle is then intact beside it (``.old``).

The knowledge is the tiny test fixture in ``tests/fixtures/kb_small`` (3 verbs, 4 objects: 7
requests per cold build), served over the OpenAI wire format by ``servers.FakeServer``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from conftest import KB_SMALL, FixtureKB, bundle_bytes
from servers import Action, CutBody, FakeServer, Received, Reply, openai_reply
from typer.testing import CliRunner

from craft_e.compiler.cache import RecordCache
from craft_e.compiler.cli import app as craftc_app
from craft_e.compiler.sources.llm import LLM_SOURCE
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.schemas.v1.payloads import ObjectProperties, VerbProperties

MODEL = "fake-llm-v1"
VERBS = ("cut", "scoop", "pour")
OBJECTS = ("knife", "spoon", "bowl", "cup")
_SUBJECT = re.compile(r'^(?:Verb|Object): "([^"]+)"', re.MULTILINE)


def fixture_answers() -> dict[str, str]:
    """Subject -> the fixture's answer JSON (what a well-behaved model would say)."""
    answers: dict[str, str] = {}
    for name, key in (("verb_properties.jsonl", "verb"), ("object_properties.jsonl", "object")):
        for line in (KB_SMALL / name).read_text(encoding="utf-8").splitlines():
            if line.strip() and not line.startswith("//"):
                row = json.loads(line)
                answers[row[key]] = json.dumps(row)
    assert set(answers) == set(VERBS) | set(OBJECTS)
    return answers


ANSWERS = fixture_answers()


def subject_of(request: Received) -> str:
    """The verb or object a chat-completions request asks about (from the rendered prompt)."""
    users = [m["content"] for m in request.json()["messages"] if m["role"] == "user"]
    found = _SUBJECT.search(users[0]) if users else None
    assert found, f"no subject in {users!r}"
    return found.group(1)


@dataclass
class GatedResponder:
    """Answers the first ``answer_first`` requests after ``delay_s``, holds the rest open.

    Held requests wait on ``release`` (set when the test ends), so the build under test is
    blocked on the network exactly when it is killed.
    """

    answer_first: int
    delay_s: float = 0.2
    release: threading.Event = field(default_factory=threading.Event)
    answered: list[str] = field(default_factory=list)
    held: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __call__(self, request: Received) -> Action:
        subject = subject_of(request)
        with self._lock:
            turn = len(self.answered) < self.answer_first
            if turn:
                self.answered.append(subject)
            else:
                self.held += 1
        if turn:
            time.sleep(self.delay_s)
            return openai_reply(ANSWERS[subject])
        self.release.wait(60)
        return openai_reply(ANSWERS[subject])


def _prompt_answer(request: Received) -> Action:
    return openai_reply(ANSWERS[subject_of(request)])


@pytest.fixture
def fresh_cache(kb_a: FixtureKB, tmp_path: Path) -> Path:
    """An empty record cache with the fixture's text embeddings (no encoder load)."""
    cache = tmp_path / "cache"
    shutil.copytree(kb_a.cache / "embeddings", cache / "embeddings")
    return cache


def build_args(url: str, cache: Path, out: Path) -> list[str]:
    return ["build", "--provider", "openai", "--base-url", f"{url}/v1", "--model", MODEL,
            "--verbs", str(KB_SMALL / "verbs.txt"), "--objects", str(KB_SMALL / "objects.txt"),
            "--out", str(out), "--name", "fault-kb", "--cache", str(cache), "--quiet",
            "--force", "--prompts", "v1"]  # the previous bundle at --out (a copy of kb_a) has another kb name


def craftc_process(args: list[str]) -> subprocess.Popen[str]:
    """``craftc ARGS`` in its own process (so it can be SIGKILLed), without any API key."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENAI_API_KEY", "GEMINI_API_KEY")}
    env.update(HF_HUB_OFFLINE="1", TRANSFORMERS_OFFLINE="1")
    code = "import sys; from craft_e.compiler.cli import app; sys.exit(app(prog_name='craftc'))"
    return subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


def records(cache: Path) -> dict[str, str]:
    """Record file name -> subject, for every (valid) record in the cache."""
    return {p.name: r.request.subject for p, r in RecordCache(cache).iter_records(LLM_SOURCE)}


def wait_for(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def assert_payloads_valid(cache: Path) -> None:
    """Every record re-hashes to its key and its payload passes its prompt's model."""
    report = RecordCache(cache).verify()
    assert report.ok, (report.corrupt, report.orphaned)
    for _, record in RecordCache(cache).iter_records(LLM_SOURCE):
        model = VerbProperties if record.request.prompt.startswith("verb_properties") else ObjectProperties
        model.model_validate(record.payload)
        assert record.request.provider == "openai" and record.request.model == MODEL


def cache_verify_cli(cache: Path) -> tuple[int, str]:
    r = CliRunner().invoke(craftc_app, ["cache", "verify", "--cache", str(cache)])
    return r.exit_code, r.output


@pytest.fixture(scope="module")
def uninterrupted(kb_a: FixtureKB, tmp_path_factory: pytest.TempPathFactory) -> str:
    """Content hash of the same build run without faults (the reference a resumed build meets)."""
    root = tmp_path_factory.mktemp("uninterrupted")
    shutil.copytree(kb_a.cache / "embeddings", root / "cache" / "embeddings")
    with FakeServer(responder=_prompt_answer) as server:
        r = CliRunner().invoke(craftc_app, build_args(server.url, root / "cache", root / "out"))
        assert r.exit_code == 0, r.output
    return load_bundle(root / "out", check_encoder=False).manifest.content_sha256


# -- (a) SIGKILL mid-build ----------------------------------------------------------------------


@pytest.mark.parametrize(("answer_first", "previous"), [(2, False), (5, True)],
                         ids=["killed-in-stage1-no-previous-bundle", "killed-in-stage2-previous-bundle"])
def test_sigkill_midway_keeps_cache_and_out_consistent_and_rerun_resumes(
    answer_first: int, previous: bool, kb_a: FixtureKB, fresh_cache: Path, tmp_path: Path, uninterrupted: str,
) -> None:
    out = tmp_path / "kb" / "fault-kb"
    out.parent.mkdir()
    if previous:  # a bundle from an earlier build sits at --out
        shutil.copytree(kb_a.bundle, out)
    before = bundle_bytes(out) if previous else None
    gate = GatedResponder(answer_first)
    try:
        with FakeServer(responder=gate) as server:
            proc = craftc_process(build_args(server.url, fresh_cache, out))
            try:
                wait_for(lambda: len(records(fresh_cache)) == answer_first and gate.held >= 1, 60,
                         f"{answer_first} records and a held request")
            finally:
                os.kill(proc.pid, signal.SIGKILL)
                _, errors = proc.communicate(timeout=30)
            assert proc.returncode == -signal.SIGKILL, errors
    finally:
        gate.release.set()

    # the cache: exactly the answered subjects, every record whole and valid, no leftovers
    assert sorted(records(fresh_cache).values()) == sorted(gate.answered)
    assert_payloads_valid(fresh_cache)
    code, output = cache_verify_cli(fresh_cache)
    assert code == 0, output
    assert f"checked {answer_first} records: 0 corrupt, 0 orphaned" in output
    # --out: absent, or the previous bundle byte for byte; no staging folder next to it
    if previous:
        assert bundle_bytes(out) == before
        load_bundle(out, check_encoder=False)
    else:
        assert not out.exists()
    assert [p.name for p in out.parent.iterdir()] == (["fault-kb"] if previous else [])

    # rerun: completes, and the server is asked only for what was not recorded
    with FakeServer(responder=_prompt_answer) as server:
        proc = craftc_process(build_args(server.url, fresh_cache, out))
        stdout, errors = proc.communicate(timeout=120)
        assert proc.returncode == 0, errors
        asked = sorted(subject_of(r) for r in server.received)
    missing = sorted((set(VERBS) | set(OBJECTS)) - set(gate.answered))
    assert asked == missing
    assert load_bundle(out, check_encoder=False).manifest.content_sha256 == uninterrupted
    assert "built fault-kb" in stdout
    assert_payloads_valid(fresh_cache)


def test_a_write_interrupted_inside_the_rename_window_is_an_orphan_not_corruption(
    fresh_cache: Path, tmp_path: Path,
) -> None:
    """What a kill between ``mkstemp`` and ``os.replace`` leaves: a partial ``.<key>.json.*.tmp``."""
    with FakeServer(responder=_prompt_answer) as server:
        r = CliRunner().invoke(craftc_app, build_args(server.url, fresh_cache, tmp_path / "out"))
        assert r.exit_code == 0, r.output
    name = sorted(records(fresh_cache))[0]
    leftover = fresh_cache / LLM_SOURCE / f".{name}.k1ll3d.tmp"
    leftover.write_bytes((fresh_cache / LLM_SOURCE / name).read_bytes()[:57])
    code, output = cache_verify_cli(fresh_cache)
    assert code == 1 and "0 corrupt, 1 orphaned" in output and "orphaned:" in output
    # builds never read temporary files: the next build replays the 7 records untouched
    with FakeServer(responder=_prompt_answer) as server:
        r = CliRunner().invoke(craftc_app, build_args(server.url, fresh_cache, tmp_path / "out2"))
        assert r.exit_code == 0, r.output
        assert server.received == []


_KILL_IN_SWAP = """
import os, signal, sys
from pathlib import Path

out = Path(sys.argv[1]).resolve()
real_replace = os.replace

def replace(src, dst, *args, **kwargs):  # SIGKILL between 'out -> .old' and 'staging -> out'
    if Path(dst).resolve() == out and Path(src).name.endswith(".tmp"):
        os.kill(os.getpid(), signal.SIGKILL)
    return real_replace(src, dst, *args, **kwargs)

os.replace = replace
from craft_e.compiler.cli import app
sys.exit(app(args=sys.argv[2:], prog_name="craftc"))
"""


def test_a_kill_inside_the_bundle_swap_leaves_the_previous_bundle_recoverable(
    kb_a: FixtureKB, fresh_cache: Path, tmp_path: Path,
) -> None:
    """The one window where ``--out`` is briefly absent: between the swap's two renames.

    ``emit.write_bundle`` moves the previous bundle aside (``.<name>.*.old``), then renames the
    complete staging folder into place; a SIGKILL between the two (no cleanup can run) leaves no
    bundle at ``--out``, the previous one intact beside it and the new one complete in staging.
    """
    out = tmp_path / "kb" / "fault-kb"
    shutil.copytree(kb_a.bundle, out)
    before = bundle_bytes(out)
    env = {k: v for k, v in os.environ.items() if k != "OPENAI_API_KEY"}
    with FakeServer(responder=_prompt_answer) as server:
        proc = subprocess.run([sys.executable, "-c", _KILL_IN_SWAP, str(out), *build_args(server.url, fresh_cache, out)],
                              capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert not out.exists()
    (old,) = out.parent.glob(".fault-kb.*.old")
    assert bundle_bytes(old) == before  # the previous bundle, byte for byte
    (staging,) = out.parent.glob(".fault-kb.*.tmp")
    load_bundle(staging, check_encoder=False)  # the new bundle, complete and verifiable
    assert_payloads_valid(fresh_cache)
    # the next build needs nothing from the server and puts a bundle back at --out
    with FakeServer(responder=_prompt_answer) as server:
        r = CliRunner().invoke(craftc_app, build_args(server.url, fresh_cache, out))
        assert r.exit_code == 0 and server.received == [], r.output
    load_bundle(out, check_encoder=False)


# -- (b) a misbehaving LLM server ---------------------------------------------------------------

HOLD_S = 2.5  # a "timed out" request is held this long; the client gives up after TIMEOUT_S
TIMEOUT_S = 0.5


@dataclass
class FaultScript:
    """Per subject: the faults to answer its first requests with, then the real answer.

    ``always`` subjects never get a valid answer. Every request is counted per subject.
    """

    faults: dict[str, list[str]]
    always: dict[str, str] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __call__(self, request: Received) -> Action:
        subject = subject_of(request)
        with self._lock:
            n = self.counts.get(subject, 0)
            self.counts[subject] = n + 1
        planned = self.faults.get(subject, [])
        fault = self.always.get(subject) or (planned[n] if n < len(planned) else None)
        return answer_with(fault, subject)


def answer_with(fault: str | None, subject: str) -> Action:
    if fault is None:
        return openai_reply(ANSWERS[subject])
    if fault == "timeout":
        threading.Event().wait(HOLD_S)  # not time.sleep: tests may stub it for backoffs
        return openai_reply(ANSWERS[subject])
    if fault == "429":
        return Reply(429, {"error": {"message": "rate limited"}}, headers={"Retry-After": "0"})
    if fault == "500":
        return Reply(500, {"error": {"message": "upstream overloaded"}})
    if fault == "cut":
        return CutBody()
    if fault == "not-json":
        return Reply(200, b"<html>502 Bad Gateway</html>")
    if fault == "invalid-answer":  # well-formed wire format, but the answer breaks the schema
        return openai_reply(json.dumps({"verb": subject, "properties": [{"name": "sharp", "weight": 7}]})
                            if subject in VERBS else "Sure! Here are the scores you asked for.")
    raise AssertionError(fault)


@pytest.fixture
def short_timeouts(monkeypatch: pytest.MonkeyPatch) -> None:
    """The CLI's HTTP client with a 0.5 s read timeout (120 s by default: a model may think)."""
    import craft_e.compiler.sources.http_retry as http_retry

    monkeypatch.setattr(http_retry, "READ_TIMEOUT_S", TIMEOUT_S)
    monkeypatch.setattr(http_retry, "CONNECT_TIMEOUT_S", TIMEOUT_S)


@pytest.fixture
def backoffs(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[float]]:
    """Record the retry loop's backoff sleeps instead of sleeping them."""
    slept: list[float] = []
    monkeypatch.setattr(time, "sleep", slept.append)
    yield slept


def test_transient_faults_are_retried_and_one_dead_subject_fails_the_build_by_name(
    fresh_cache: Path, tmp_path: Path, short_timeouts: None, backoffs: list[float],
) -> None:
    script = FaultScript(
        faults={"cut": ["429", "500"], "scoop": ["cut"], "pour": ["not-json", "invalid-answer"],
                "knife": ["timeout"], "spoon": ["invalid-answer", "cut", "500"]},
        always={"cup": "500"},
    )
    out = tmp_path / "out"
    with FakeServer(responder=script) as server:
        r = CliRunner().invoke(craftc_app, build_args(server.url, fresh_cache, out))
    assert r.exit_code == 3, r.output
    message = " ".join(r.output.split())
    assert "subject='cup'" in message and "after 4 attempts" in message and "HTTP 500" in message
    assert not out.exists()
    # bounded: every subject asked (faults + 1) times, the dead one exactly max_attempts times
    assert script.counts == {"cut": 3, "scoop": 2, "pour": 3, "knife": 2, "spoon": 4, "bowl": 1, "cup": 4}
    assert all(0 <= s <= 60 for s in backoffs) and len(backoffs) == 2 + 1 + 2 + 1 + 3 + 3
    # recorded: the six good answers, nothing for cup, nothing invalid
    assert sorted(records(fresh_cache).values()) == sorted((set(VERBS) | set(OBJECTS)) - {"cup"})
    assert_payloads_valid(fresh_cache)
    assert cache_verify_cli(fresh_cache)[0] == 0
    # once the server recovers, only cup is asked again
    with FakeServer(responder=_prompt_answer) as server:
        r = CliRunner().invoke(craftc_app, build_args(server.url, fresh_cache, out))
        assert r.exit_code == 0, r.output
        assert [subject_of(q) for q in server.received] == ["cup"]
    load_bundle(out, check_encoder=False)


@pytest.mark.parametrize("fault", ["timeout", "429", "500", "cut", "not-json", "invalid-answer"])
def test_a_subject_that_never_gets_a_valid_answer_is_named(
    fault: str, fresh_cache: Path, tmp_path: Path, short_timeouts: None, backoffs: list[float],
) -> None:
    script = FaultScript(faults={}, always={"scoop": fault})
    with FakeServer(responder=script) as server:
        r = CliRunner().invoke(craftc_app, build_args(server.url, fresh_cache, tmp_path / "out"))
    assert r.exit_code == 3, r.output
    message = " ".join(r.output.split())
    assert "subject='scoop'" in message and "after 4 attempts" in message
    assert script.counts["scoop"] == 4  # bounded: max_attempts, then give up
    assert backoffs and max(backoffs) <= 60  # Retry-After hints are honoured but capped
    assert "scoop" not in records(fresh_cache).values()
    assert_payloads_valid(fresh_cache)
    assert not (tmp_path / "out").exists()
