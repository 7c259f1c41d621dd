"""``examples/overrides.toml``, the README's example of a KB author's edits, builds and does what
its comments say, on the shipped records (replayed: no network).

Also pins two things it exposed: a reweighted verb -> property edge keeps its answer's role
(``required`` / ``helpful``; it was dropped, so a reweighted required property lost its veto), and
``craftc explain`` prints an override's provenance whole (cut to 12 characters, like record keys,
it read ``override:ove``).
"""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from craft_e.compiler.cli import app
from craft_e.paths import CACHE_DIR, VOCAB_DIR
from craft_e.runtime.grounding.explain import short_record

ROOT = Path(__file__).resolve().parents[1]


def _flat(text: str) -> str:
    return " ".join(text.split())


def test_the_overrides_example_builds_and_does_what_it_says(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    cache.mkdir()
    (cache / "llm").symlink_to(CACHE_DIR / "llm")  # the shipped records, read only; embeddings go here
    lines = (VOCAB_DIR / "default_objects.txt").read_text(encoding="utf-8").splitlines()
    objects = tmp_path / "objects.txt"
    objects.write_text("\n".join(line for line in lines if line.split("\t")[0] in {"knife", "spoon", "scissors"})
                       + "\n", encoding="utf-8")
    verbs = tmp_path / "verbs.txt"
    verbs.write_text("cut\n", encoding="utf-8")
    out = tmp_path / "kb"
    runner = CliRunner()
    build = ["build", "--verbs", str(verbs), "--objects", str(objects), "--mode", "llm+direct", "--property-pass",
             "--object-pass", "reuse", "--energy-form", "normalized-product", "--name", "ov", "--cache", str(cache),
             "--quiet", "--out"]
    plain = runner.invoke(app, [*build, str(tmp_path / "plain")])
    assert plain.exit_code == 0, plain.output
    result = runner.invoke(app, [*build, str(out), "--overrides", str(ROOT / "examples" / "overrides.toml")])
    assert result.exit_code == 0, result.output
    assert runner.invoke(app, ["validate", str(out)]).exit_code == 0

    before = _flat(runner.invoke(app, ["explain", str(tmp_path / "plain"), "cut", "scissors"]).output)
    scissors = _flat(runner.invoke(app, ["explain", str(out), "cut", "scissors"]).output)
    assert "-(0.85)-> is a cutting tool (helpful)" in before and "used to cut" in before
    assert "-(0.70)-> is a cutting tool (helpful) -(1.00)-> scissors" in scissors  # reweighted, role kept
    assert "override:overrides.toml:9" in scissors
    assert "used to cut" not in scissors  # the removed edge
    spoon = _flat(runner.invoke(app, ["explain", str(out), "cut", "spoon"]).output)
    assert "E_aff = +1.0000" in spoon and "forbidden" in spoon


def test_explain_shortens_record_keys_only() -> None:
    key = "6126986e29e4" + "0" * 52
    assert short_record(key) == "6126986e29e4"
    assert short_record("override:overrides.toml:9") == "override:overrides.toml:9"
