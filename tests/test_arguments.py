"""``craft_e.arguments``: the benchmark scripts' count type."""

from __future__ import annotations

import argparse
from pathlib import Path
from types import ModuleType

import pytest
from conftest import load_script

from craft_e.arguments import number_list, output_file, positive_int

BENCH_SCALE = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_scale.py"


def _bench_scale() -> ModuleType:
    return load_script(BENCH_SCALE)


def test_positive_int_accepts_counts_and_names_what_is_wrong() -> None:
    assert positive_int("3") == 3
    for text, message in (("0", "0 must be at least 1"), ("-1", "-1 must be at least 1"), ("x", "'x' is not")):
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            positive_int(text)


@pytest.mark.parametrize(("sizes", "message"), [("abc", "'abc' is not VERBSxOBJECTS"), ("10x0", "0 must be at least 1"),
                                                 ("10x20,5", "'5' is not VERBSxOBJECTS")])
def test_bench_scale_sizes_fail_at_parse_time(sizes: str, message: str, capsys: pytest.CaptureFixture[str]) -> None:
    """``bench_scale.py --sizes abc`` was a traceback after argument parsing; now exit 2, naming it."""
    bench_scale = _bench_scale()
    with pytest.raises(SystemExit) as stopped:
        bench_scale.main(["--sizes", sizes])
    assert stopped.value.code == 2
    assert message in capsys.readouterr().err


def test_bench_scale_default_sizes_parse() -> None:
    bench_scale = _bench_scale()
    assert bench_scale._sizes(bench_scale.DEFAULT_SIZES) == [(100, 400), (300, 3000), (1000, 10000)]


def test_output_file_refuses_a_folder_or_a_missing_folder(tmp_path: Path) -> None:
    """--json/--markdown/--plot of the benchmarks were written after minutes of work, then failed."""
    assert output_file(str(tmp_path / "rows.json")) == tmp_path / "rows.json"
    with pytest.raises(argparse.ArgumentTypeError, match="is a folder"):
        output_file(str(tmp_path))
    with pytest.raises(argparse.ArgumentTypeError, match="does not exist"):
        output_file(str(tmp_path / "missing" / "rows.json"))


def test_number_list_names_the_bad_entry() -> None:
    assert number_list("0,0.5,1") == [0.0, 0.5, 1.0]
    for text, message in (("1,x", "'x' is not a number"), ("-1", "'-1' must be"), ("nan", "'nan' must be")):
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            number_list(text)
