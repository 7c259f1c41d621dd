"""``craftc`` through typer's CliRunner: exit codes and what the user reads.

Exit codes are the CLI's contract with CI scripts (0 ok; 1 a check failed; 2 bad input or usage;
3 a source could not answer), and every error must name the file or record and the fix.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
from conftest import KB_NAME, KB_SMALL, MODEL, PROVIDER, FixtureKB, bundle_bytes, fixture_source
from typer.testing import CliRunner, Result

from craft_e.compiler.cli import app
from craft_e.compiler.diff import diff_bundles
from craft_e.compiler.llm_knowledge import verb_call
from craft_e.compiler.sources.llm import LLM_SOURCE
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.schemas.generate import SCHEMA_DIR, generate_all

runner = CliRunner()


def craftc(*args: str | Path) -> Result:
    """Run ``craftc`` in-process; a wide console keeps long paths on one line."""
    return runner.invoke(app, [str(a) for a in args], env={"COLUMNS": "2000"})


def flat(text: str) -> str:
    """Output with line breaks removed (the console may still wrap very long lines)."""
    return text.replace("\n", "")


def replay_args(cache: Path, out: Path, verbs: str = "verbs.txt") -> list[str | Path]:
    return [
        "build", "--verbs", KB_SMALL / verbs, "--objects", KB_SMALL / "objects.txt",
        "--cache", cache, "--out", out, "--name", KB_NAME,
        "--record-provider", PROVIDER, "--model", MODEL, "--quiet", "--prompts", "v1",
    ]  # fmt: skip


# --- build -----------------------------------------------------------------------------------


def test_build_replays_the_fixture(kb_a: FixtureKB, tmp_path: Path) -> None:
    result = craftc(*replay_args(kb_a.cache, tmp_path / "bundle"))
    assert result.exit_code == 0, result.output
    sha = load_bundle(kb_a.bundle).manifest.content_sha256
    assert f"built {KB_NAME} 1.0.0 -> {tmp_path / 'bundle'}" in flat(result.stdout)
    assert f"content sha256 {sha}" in flat(result.stdout)
    assert "3 verbs, 19 properties, 4 objects" in result.stdout
    assert "embeddings 29 cached / 0 computed" in result.stdout


def test_build_unknown_provider_is_a_usage_error(kb_a: FixtureKB, tmp_path: Path) -> None:
    result = craftc(*replay_args(kb_a.cache, tmp_path / "bundle"), "--provider", "bogus")
    assert result.exit_code == 2
    assert "unknown provider 'bogus'; choose one of replay, openai, gemini" in flat(result.output)
    assert not (tmp_path / "bundle").exists()


def test_build_unknown_mode_and_missing_vocabulary(kb_a: FixtureKB, tmp_path: Path) -> None:
    result = craftc(*replay_args(kb_a.cache, tmp_path / "b"), "--mode", "magic")
    assert result.exit_code == 2 and "unknown mode 'magic'" in result.output
    args = replay_args(kb_a.cache, tmp_path / "b", verbs="no-such-verbs.txt")
    result = craftc(*args)
    assert result.exit_code == 2
    assert f"{KB_SMALL / 'no-such-verbs.txt'}: file not found" in flat(result.output)


def test_replay_miss_exits_3_naming_subject_and_record_path(
    kb_a: FixtureKB, tmp_path: Path
) -> None:
    out = tmp_path / "bundle"
    result = craftc(*replay_args(kb_a.cache, out, verbs="verbs_stir.txt"))
    assert result.exit_code == 3, result.output
    key = fixture_source(kb_a.cache).request_for(verb_call("stir", version="v1")).key()
    text = flat(result.output)
    assert "no record for verb_properties@v1 subject='stir'" in text
    assert f"expected {kb_a.cache / LLM_SOURCE / f'{key}.json'}" in text
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_replay_miss_leaves_a_previous_bundle_intact(kb_a: FixtureKB, tmp_path: Path) -> None:
    out = tmp_path / "bundle"
    shutil.copytree(kb_a.bundle, out)
    before = bundle_bytes(out)
    result = craftc(*replay_args(kb_a.cache, out, verbs="verbs_stir.txt"))
    assert result.exit_code == 3
    assert bundle_bytes(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["bundle"]
    assert craftc("validate", out).exit_code == 0


def test_curate_then_build_then_validate(kb_a: FixtureKB, tmp_path: Path) -> None:
    """The KB author's loop on a scratch cache: store written answers, build, validate."""
    cache, out = tmp_path / "cache", tmp_path / "bundle"
    shutil.copytree(kb_a.cache / "embeddings", cache / "embeddings")  # no encoder run needed
    vocab: list[str | Path] = [
        "--verbs",
        KB_SMALL / "verbs.txt",
        "--objects",
        KB_SMALL / "objects.txt",
        "--prompts",
        "v1",
    ]
    for prompt, answers in (
        ("verb_properties", "verb_properties.jsonl"),
        ("object_properties", "object_properties.jsonl"),
    ):
        result = craftc(
            "curate",
            "record",
            "--prompt",
            prompt,
            "--answers",
            KB_SMALL / answers,
            *vocab,
            "--cache",
            cache,
        )
        assert result.exit_code == 0, result.output
    assert "stored 4 records, 0 unchanged, 0 skipped" in result.stdout
    again = craftc(
        "curate",
        "record",
        "--prompt",
        "object_properties",
        "--answers",
        KB_SMALL / "object_properties.jsonl",
        *vocab,
        "--cache",
        cache,
    )
    assert "0 records" in again.stdout and "4 skipped" in again.stdout  # nothing pending
    pending = craftc("curate", "pending", *vocab, "--cache", cache)
    assert pending.exit_code == 0 and json.loads(pending.stdout) == []
    result = craftc("build", *vocab, "--cache", cache, "--out", out, "--name", "scratch", "--quiet")
    assert result.exit_code == 0, result.output
    assert craftc("validate", out).exit_code == 0



def test_curate_never_rewrites_and_stores_all_or_nothing(tmp_path: Path) -> None:
    """A revised answer to a recorded prompt is refused (stored answers are never rewritten), a
    bad line stores none of the file, two answers to one prompt are refused, and a verb outside
    the verbs file is named and fails the run (exit 1) without undoing what was stored."""
    cache = tmp_path / "cache"
    args: list[str | Path] = ["--prompt", "verb_properties", "--verbs", KB_SMALL / "verbs.txt",
                              "--cache", cache, "--prompts", "v1"]
    lines = (KB_SMALL / "verb_properties.jsonl").read_text(encoding="utf-8").splitlines()
    scoop = next(line for line in lines if '"scoop"' in line)
    revised = (KB_SMALL / "scoop_v2.verb_properties.jsonl").read_text(encoding="utf-8").splitlines()[-1]
    first = tmp_path / "first.jsonl"
    first.write_text(scoop + "\n", encoding="utf-8")
    assert craftc("curate", "record", "--answers", first, *args).exit_code == 0
    stored = {p.name: p.read_bytes() for p in (cache / LLM_SOURCE).iterdir()}

    def record(*rows: str) -> Result:
        answers = tmp_path / "answers.jsonl"
        answers.write_text("".join(r + "\n" for r in rows), encoding="utf-8")
        return craftc("curate", "record", "--answers", answers, *args)

    cut = next(line for line in lines if '"cut"' in line)
    for rows, message in (((cut, revised), ":2: the prompt (verb_properties@v1 subject='scoop') already has a "
                                           "different stored answer"),
                          ((cut, cut), ":2: answers the same prompt as"),
                          ((cut, '{"verb": "cut", "properties": []}'), ":2: properties")):
        result = record(*rows)
        assert result.exit_code == 2 and message in flat(result.output), result.output
        assert {p.name: p.read_bytes() for p in (cache / LLM_SOURCE).iterdir()} == stored  # nothing stored
    unknown = cut.replace('"cut"', '"whittle"')
    result = record(scoop, unknown)
    # the known answer is stored (here: already was), the unknown one named and the run fails
    assert result.exit_code == 1 and ":2: 'whittle' is not in the verbs file" in flat(result.output)
    assert "1 answer(s) of" in flat(result.output) and "were not stored" in flat(result.output)
    assert "stored 0 records, 1 unchanged, 1 skipped" in result.stdout
    assert {p.name: p.read_bytes() for p in (cache / LLM_SOURCE).iterdir()} == stored

def test_curate_bad_answer_names_file_and_line(tmp_path: Path) -> None:
    answers = tmp_path / "answers.jsonl"
    answers.write_text('// fixture\n{"verb": "cut", "properties": []}\n', encoding="utf-8")
    result = craftc(
        "curate",
        "record",
        "--prompt",
        "verb_properties",
        "--answers",
        answers,
        "--verbs",
        KB_SMALL / "verbs.txt",
        "--objects",
        KB_SMALL / "objects.txt",
        "--cache",
        tmp_path / "cache",
        "--prompts",
        "v1",
    )
    assert result.exit_code == 2
    assert f"{answers}:2: properties" in flat(result.output)
    answers.write_text("not json\n", encoding="utf-8")
    result = craftc(
        "curate",
        "record",
        "--prompt",
        "verb_properties",
        "--answers",
        answers,
        "--verbs",
        KB_SMALL / "verbs.txt",
        "--cache",
        tmp_path / "cache",
    )
    assert result.exit_code == 2 and f"{answers}:1: not JSON" in flat(result.output)
    assert not (tmp_path / "cache" / LLM_SOURCE).exists()


# --- validate --------------------------------------------------------------------------------


def test_validate_ok(kb_a: FixtureKB) -> None:
    result = craftc("validate", kb_a.bundle)
    sha = load_bundle(kb_a.bundle).manifest.content_sha256
    assert result.exit_code == 0
    assert result.stdout.strip() == f"ok: {KB_NAME} 1.0.0 content sha256 {sha}"


def test_validate_tampered_file_exits_1_naming_it(kb_a: FixtureKB, tmp_path: Path) -> None:
    bundle = tmp_path / "bundle"
    shutil.copytree(kb_a.bundle, bundle)
    graph = bundle / "graph.json"
    data = bytearray(graph.read_bytes())
    data[len(data) // 2] ^= 0x01  # flip one bit; the size stays the same
    graph.write_bytes(bytes(data))
    result = craftc("validate", bundle)
    assert result.exit_code == 1
    assert f"{graph}: content does not match the manifest" in flat(result.output)


def test_validate_refuses_schema_version_2(kb_a: FixtureKB, tmp_path: Path) -> None:
    bundle = tmp_path / "bundle"
    shutil.copytree(kb_a.bundle, bundle)
    manifest = bundle / "manifest.json"
    data = json.loads(manifest.read_text("utf-8"))
    manifest.write_text(json.dumps({**data, "schema_version": 2}), encoding="utf-8")
    result = craftc("validate", bundle)
    assert result.exit_code == 1
    assert f"{manifest}: schema_version 2 is not supported" in flat(result.output)


def test_validate_missing_file_and_not_a_bundle(kb_a: FixtureKB, tmp_path: Path) -> None:
    bundle = tmp_path / "bundle"
    shutil.copytree(kb_a.bundle, bundle)
    (bundle / "affordance_energy.npy").unlink()
    result = craftc("validate", bundle)
    assert result.exit_code == 1 and "affordance_energy.npy: missing" in flat(result.output)
    result = craftc("validate", tmp_path / "nowhere")
    assert result.exit_code == 1 and "not a bundle folder" in result.output


# --- explain, review -------------------------------------------------------------------------


def test_explain(kb_a: FixtureKB) -> None:
    pytest.importorskip("craft_e.runtime.grounding.explain", reason="runtime/grounding/explain.py not written yet")
    result = craftc("explain", kb_a.bundle, "cut", "knife")
    assert result.exit_code == 0, result.output
    for name in ("cut", "knife", "sharp edge", "has a blade"):
        assert name in result.stdout
    unknown = craftc("explain", kb_a.bundle, "whisk", "knife")
    assert unknown.exit_code == 2 and "whisk" in unknown.output


_PATH_LINE = re.compile(
    r"^(?P<v>[a-z ]+) -\((?P<w1>\d\.\d\d)\)-> (?P<p>[a-z -]+) -\((?P<w2>\d\.\d\d)\)-> (?P<o>[a-z ]+)$"
)


def test_review_prints_sampled_paths(kb_a: FixtureKB) -> None:
    result = craftc("review", kb_a.bundle, "--sample", "4", "--seed", "1")
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert len(lines) == 4
    known = {(p.verb, p.prop, p.obj) for p in load_bundle(kb_a.bundle).paths()}
    for line in lines:
        match = _PATH_LINE.match(line)
        assert match, line
        assert (match["v"], match["p"], match["o"]) in known
    assert craftc("review", kb_a.bundle, "--sample", "4", "--seed", "1").stdout == result.stdout
    everything = craftc("review", kb_a.bundle, "--sample", "1000")
    assert len(everything.stdout.splitlines()) == len(known)
    assert craftc("review", Path("/nonexistent/bundle")).exit_code == 2


# --- cache -----------------------------------------------------------------------------------


def test_cache_verify_and_stats(kb_a: FixtureKB) -> None:
    result = craftc("cache", "verify", "--cache", kb_a.cache)
    assert result.exit_code == 0, result.output
    assert "checked 7 records: 0 corrupt, 0 orphaned" in result.stdout
    stats = craftc("cache", "stats", "--cache", kb_a.cache)
    assert stats.exit_code == 0
    llm = json.loads(stats.stdout)[LLM_SOURCE]
    assert llm["records"] == 7
    assert llm[f"{PROVIDER}:verb_properties@v1"] == 3
    assert llm[f"{PROVIDER}:object_properties@v1"] == 4


def test_cache_verify_names_corrupt_and_orphaned_files(kb_a: FixtureKB, tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    shutil.copytree(kb_a.cache / LLM_SOURCE, cache / LLM_SOURCE)
    victim = sorted((cache / LLM_SOURCE).glob("*.json"))[0]
    victim.write_text("{}", encoding="utf-8")
    orphan = cache / LLM_SOURCE / f".{victim.name}.x1y2.tmp"
    orphan.write_bytes(b"")
    result = craftc("cache", "verify", "--cache", cache)
    assert result.exit_code == 1
    text = flat(result.output)
    assert f"corrupt: {victim}: not a valid v1 record" in text
    assert f"orphaned: {orphan}" in text
    assert "checked 7 records: 1 corrupt, 1 orphaned" in text


# --- schema ----------------------------------------------------------------------------------


def test_schema_prints_every_schema() -> None:
    result = craftc("schema")
    assert result.exit_code == 0
    assert json.loads(result.stdout) == generate_all()
    assert str(SCHEMA_DIR) in flat(result.stderr)


def test_schema_write_reproduces_the_committed_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import craft_e.schemas.generate as generate

    monkeypatch.setattr(generate, "SCHEMA_DIR", tmp_path / "json")
    result = craftc("schema", "--write")
    assert result.exit_code == 0
    written = sorted(p.name for p in (tmp_path / "json").iterdir())
    assert written == sorted(p.name for p in SCHEMA_DIR.glob("*.schema.json"))
    for name in written:
        assert (tmp_path / "json" / name).read_bytes() == (SCHEMA_DIR / name).read_bytes(), name


# --- diff ------------------------------------------------------------------------------------


def test_diff_markdown(kb_a: FixtureKB, kb_scoop_v2: FixtureKB) -> None:
    result = craftc("diff", kb_a.bundle, kb_scoop_v2.bundle)
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith("## KB diff: `fixture-kb` 1.0.0")
    assert "| `scoop` ⚠️ | `spoon` | `cup` | — | — |" in result.stdout


def test_diff_json_equals_the_library_result(kb_a: FixtureKB, kb_scoop_v2: FixtureKB) -> None:
    result = craftc("diff", kb_a.bundle, kb_scoop_v2.bundle, "--format", "json", "--top-k", "2")
    assert result.exit_code == 0, result.output
    expected = diff_bundles(load_bundle(kb_a.bundle), load_bundle(kb_scoop_v2.bundle), top_k=2)
    assert json.loads(result.stdout) == expected


def test_diff_fail_on_top1_changed_exits_1(kb_a: FixtureKB, kb_scoop_v2: FixtureKB) -> None:
    result = craftc("diff", kb_a.bundle, kb_scoop_v2.bundle, "--fail-on", "top1-changed")
    assert result.exit_code == 1
    assert "gate failed: top1-changed" in result.output
    assert "scoop (spoon -> cup)" in flat(result.output)
    passing = craftc(
        "diff",
        kb_a.bundle,
        kb_scoop_v2.bundle,
        "--fail-on",
        "weight-changes>3",
        "--fail-on",
        "verb-removed",
    )
    assert passing.exit_code == 0, passing.output
    same = craftc("diff", kb_a.bundle, kb_a.bundle, "--fail-on", "any-change")
    assert same.exit_code == 0 and "No changes" in same.stdout


def test_diff_usage_errors(kb_a: FixtureKB, tmp_path: Path) -> None:
    bad_rule = craftc("diff", kb_a.bundle, kb_a.bundle, "--fail-on", "everything")
    assert bad_rule.exit_code == 2
    assert "unknown --fail-on rule 'everything'; valid rules: top1-changed" in flat(bad_rule.output)
    assert bad_rule.stdout == "", "a bad gate fails before the diff is printed"
    bad_k = craftc("diff", kb_a.bundle, kb_a.bundle, "--top-k", "0")
    assert bad_k.exit_code == 2 and "top_k must be at least 1" in bad_k.output
    bad_format = craftc("diff", kb_a.bundle, kb_a.bundle, "--format", "xml")
    assert bad_format.exit_code == 2 and "unknown format 'xml'" in bad_format.output
    missing = craftc("diff", kb_a.bundle, tmp_path / "nowhere")
    assert missing.exit_code == 2 and "not a bundle folder" in missing.output


def test_cache_commands_refuse_a_cache_that_does_not_exist(tmp_path: Path) -> None:
    """A mistyped --cache is an error, not an empty cache that passes ``cache verify``."""
    for command in ("verify", "index", "stats", "clean"):
        result = craftc("cache", command, "--cache", tmp_path / "typo")
        assert result.exit_code == 2, (command, result.output)
        assert "no such record cache folder" in flat(result.output)
    assert not (tmp_path / "typo").exists()
