"""``benchmarks/bench_load.py``: the medians it reports, the file it writes, a bad bundle named."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from runtime_fixtures import RuntimeKBs, runtime_kbs_fixture  # noqa: F401
from script_loader import load_benchmark


def test_it_times_a_bundle_and_writes_the_medians(runtime_kbs: RuntimeKBs, tmp_path: Path) -> None:
    bench = load_benchmark("bench_load")
    out = tmp_path / "load.json"
    assert bench.main(["--bundle", str(runtime_kbs.kb), "--repeats", "2", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert (result["verbs"], result["objects"], result["repeats"]) == (6, 24, 2)
    assert 0 < result["load_s"] < 10 and 0 < result["grounder_s"] < 10


def test_a_folder_that_is_no_bundle_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bench = load_benchmark("bench_load")
    assert bench.main(["--bundle", str(tmp_path)]) == 2
    assert str(tmp_path) in capsys.readouterr().err
