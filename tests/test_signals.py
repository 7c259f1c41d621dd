"""SIGTERM exits through Python, so cleanup hooks run (``craft_e.signals``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def test_sigterm_runs_atexit_hooks_and_exits_143(tmp_path: Path) -> None:
    marker = tmp_path / "cleaned"
    code = (
        "import atexit, os, signal, pathlib\n"
        "from craft_e.signals import exit_through_python_on_sigterm\n"
        "exit_through_python_on_sigterm()\n"
        f"atexit.register(pathlib.Path({str(marker)!r}).write_text, 'yes')\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "signal.pause()\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=30)
    assert done.returncode == 143, done.stderr
    assert marker.read_text() == "yes"
