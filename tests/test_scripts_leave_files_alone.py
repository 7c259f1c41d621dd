"""Maintenance scripts must not change what they did not mean to: re-running
``scripts/make_vocab.py`` leaves the committed vocabularies (with their glosses) as they are, and
``benchmarks/bench_build.py --workdir`` refuses a folder holding a user's files."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

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


def test_bench_build_refuses_a_workdir_with_a_users_files(tmp_path: Path) -> None:
    spec = importlib.util.spec_from_file_location("bench_build", REPO / "benchmarks" / "bench_build.py")
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = bench  # its dataclasses look their module up
    try:
        spec.loader.exec_module(bench)
    finally:
        sys.modules.pop(spec.name, None)
    (tmp_path / "verbs.txt").write_text("mine\n")
    with pytest.raises(SystemExit) as stop:
        bench.main(["--verbs", "2", "--objects", "3", "--properties", "2", "--workdir", str(tmp_path)])
    assert stop.value.code == 2
    assert (tmp_path / "verbs.txt").read_text() == "mine\n" and len(list(tmp_path.iterdir())) == 1
