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
