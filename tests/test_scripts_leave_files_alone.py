"""Maintenance scripts must not change what they did not mean to: re-running
``scripts/make_vocab.py`` leaves the committed vocabularies (with their glosses) as they are, and
``benchmarks/bench_build.py --workdir`` refuses a folder holding a user's files."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import load_script

REPO = Path(__file__).resolve().parents[1]


def test_make_vocab_is_idempotent_and_keeps_the_glosses(tmp_path: Path) -> None:
    artifacts = tmp_path / "artifacts"
    shutil.copytree(REPO / "artifacts" / "vocab", artifacts / "vocab")
    before = {p.name: p.read_bytes() for p in (artifacts / "vocab").iterdir()}
    env = {**os.environ, "CRAFT_ARTIFACTS": str(artifacts)}
    subprocess.run([sys.executable, str(REPO / "scripts" / "make_vocab.py")], cwd=REPO, env=env, check=True,
                   capture_output=True)
    after = {p.name: p.read_bytes() for p in (artifacts / "vocab").iterdir()}
    assert after == before
    assert b"\tto take hold of" in after["union_verbs.txt"]  # a gloss the shipped builds ask in


def test_make_glosses_verbs_only_is_idempotent_without_wordnet(tmp_path: Path) -> None:
    artifacts = tmp_path / "artifacts"
    shutil.copytree(REPO / "artifacts" / "vocab", artifacts / "vocab")
    before = {p.name: p.read_bytes() for p in (artifacts / "vocab").iterdir()}
    env = {**os.environ, "CRAFT_ARTIFACTS": str(artifacts)}
    done = subprocess.run([sys.executable, str(REPO / "scripts" / "make_glosses.py"), "--verbs-only"], cwd=REPO,
                          env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert {p.name: p.read_bytes() for p in (artifacts / "vocab").iterdir()} == before
    assert b"spin\tto set the object itself whirling" in before["sim_verbs.txt"]


@pytest.mark.parametrize("script", [["make_vocab.py"], ["make_glosses.py", "--verbs-only"]])
def test_vocabulary_scripts_run_elsewhere_write_nothing(tmp_path: Path, script: list[str]) -> None:
    """Run outside the checkout, the relative default made a new artifacts/vocab in that folder."""
    env = {k: v for k, v in os.environ.items() if k != "CRAFT_ARTIFACTS"}
    done = subprocess.run([sys.executable, str(REPO / "scripts" / script[0]), *script[1:]], cwd=tmp_path,
                          env=env, capture_output=True, text=True)
    assert done.returncode != 0
    assert "run this script from the checkout's root" in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_bench_build_refuses_a_workdir_with_a_users_files(tmp_path: Path) -> None:
    bench = load_script(REPO / "benchmarks" / "bench_build.py")
    (tmp_path / "verbs.txt").write_text("mine\n")
    with pytest.raises(SystemExit) as stop:
        bench.main(["--verbs", "2", "--objects", "3", "--properties", "2", "--workdir", str(tmp_path)])
    assert stop.value.code == 2
    assert (tmp_path / "verbs.txt").read_text() == "mine\n" and len(list(tmp_path.iterdir())) == 1


def test_make_vocab_help_describes_and_writes_nothing(tmp_path: Path) -> None:
    """``--help`` (or a typo'd option) ran the script: it rewrote every vocabulary file."""
    artifacts = tmp_path / "artifacts"
    shutil.copytree(REPO / "artifacts" / "vocab", artifacts / "vocab")
    (artifacts / "vocab" / "union_verbs.txt").write_text("edited by hand\n")
    env = {**os.environ, "CRAFT_ARTIFACTS": str(artifacts)}
    for args, code in ((["--help"], 0), (["--bogus"], 2)):
        done = subprocess.run([sys.executable, str(REPO / "scripts" / "make_vocab.py"), *args], cwd=REPO, env=env,
                              capture_output=True, text=True)
        assert done.returncode == code, done.stderr
        assert "usage: make_vocab.py" in done.stdout + done.stderr
    assert (artifacts / "vocab" / "union_verbs.txt").read_text() == "edited by hand\n"


def _programs() -> list[str]:
    """The scripts and benchmarks run as programs (the others are imported by them)."""
    return sorted(p.relative_to(REPO).as_posix() for folder in ("scripts", "benchmarks")
                  for p in (REPO / folder).glob("*.py")
                  if '__name__ == "__main__"' in p.read_text(encoding="utf-8"))


def test_the_program_list_is_not_empty() -> None:
    assert "scripts/make_vocab.py" in _programs() and "benchmarks/bench_perception.py" in _programs()


@pytest.mark.parametrize("script", _programs())
def test_every_script_reads_its_options_before_working(script: str) -> None:
    """A script run as a program parses its command line (argparse or typer), so ``--help`` and
    typos stop it before its work (two scripts ignored them and ran). Read from the source: running
    each would load torch and the simulator 20 times over."""
    source = (REPO / script).read_text(encoding="utf-8")
    assert "parse_args(" in source or "typer" in source, f"{script}: parse the command line (argparse) first"
