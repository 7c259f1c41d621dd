"""``evaluation.parallel.ordered_map`` and ``craft eval sim|static --jobs``: input order, same results."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest

from craft_e.runtime.evaluation.parallel import ordered_map


def _offset() -> int:
    return 10


def _add(ctx: int, item: int) -> int:
    return ctx + item * item


def test_ordered_map_keeps_input_order_in_workers_and_in_process() -> None:
    items = list(range(7))
    serial = list(ordered_map(_add, items, jobs=1, build=_offset))
    assert serial == [10 + i * i for i in items]
    assert list(ordered_map(_add, items, jobs=3, build=_offset)) == serial
    assert list(ordered_map(_add, items, jobs=1, build=_offset, context=0)) == [i * i for i in items]
    with pytest.raises(ValueError, match="jobs"):
        list(ordered_map(_add, items, jobs=0, build=_offset))


def _worker_urdf_dir(ctx: int, item: int) -> str:
    """The derived-URDF folder of the worker that runs ``item`` (made on first use)."""
    from craft_e.runtime.sim.collision_meshes import _derived_dir

    return str(_derived_dir())


def test_workers_remove_their_temporary_folders_when_the_map_ends() -> None:
    """Workers were terminated (``with Pool``), so their exit hooks never ran: every
    ``craft eval sim|static --jobs 2`` left two /tmp/craft-e-urdf-* folders behind."""
    folders = set(ordered_map(_worker_urdf_dir, list(range(4)), jobs=2, build=_offset))
    assert folders and all(folder.startswith("/") for folder in folders)
    assert not [folder for folder in folders if Path(folder).exists()]


def _slow_worker_urdf_dir(ctx: int, item: int) -> str:
    time.sleep(0.1)  # long enough that both workers take items
    return _worker_urdf_dir(ctx, item)


def test_terminated_workers_remove_their_temporary_folders() -> None:
    """An error or a stopped run terminates the pool (SIGTERM to every worker), which killed
    workers before their exit hooks ran: a ``craft eval sim --jobs 2`` stopped by ``kill`` (or
    CI's timeout) left two /tmp/craft-e-urdf-* folders behind. Workers now exit through Python."""
    seen: set[str] = set()
    with pytest.raises(RuntimeError, match="stop"):
        for folder in ordered_map(_slow_worker_urdf_dir, list(range(100)), jobs=2, build=_offset):
            seen.add(folder)
            if len(seen) == 2:  # both workers hold a folder: fail mid-map, so the pool is terminated
                raise RuntimeError("stop")
    assert not [folder for folder in seen if Path(folder).exists()]


def _cli(tmp_path: Path, command: str, jobs: int) -> dict[str, Any]:
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    labels = tmp_path / "labels.csv"
    if not labels.exists():
        labels.write_text("verb,object\ncut,knife\n")
    out = tmp_path / f"{command}-{jobs}.json"
    result = CliRunner().invoke(app, ["eval", command, "--labels", str(labels), "--max-pairs", "1",
                                      "--layouts", "2", "--methods", "CRAFT-E,direct-LLM",
                                      "--jobs", str(jobs), "--json", str(out)])
    assert result.exit_code == 0, result.output
    data: dict[str, Any] = json.loads(out.read_text())
    return data


@pytest.mark.slow
@pytest.mark.parametrize("command", ["sim", "static"])
def test_jobs_give_byte_identical_reports(tmp_path: Path, command: str) -> None:
    one = _cli(tmp_path, command, 1)
    two = _cli(tmp_path, command, 2)
    assert json.dumps(one, sort_keys=True) == json.dumps(two, sort_keys=True)


def test_jobs_beyond_the_cpus_run_one_worker_per_cpu(monkeypatch: pytest.MonkeyPatch,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """Each worker holds ~0.65 GB (encoder, grasp network, simulator): ``--jobs 64`` on a 2-core
    machine would exhaust its memory for no speed-up."""
    from craft_e.runtime.cli import common

    assert common.usable_cpus() >= 1  # the real count, before it is replaced below
    monkeypatch.setattr(common, "usable_cpus", lambda: 2)
    assert common.checked_jobs(1) == 1 and common.checked_jobs(2) == 2
    capsys.readouterr()
    assert common.checked_jobs(64) == 2
    assert "--jobs 64: this machine gives the command 2 CPUs; running 2 workers" in capsys.readouterr().err
