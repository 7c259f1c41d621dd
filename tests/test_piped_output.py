"""Piped or logged CLI output is not wrapped at 80 columns (hashes and paths stay on one line)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from craft_e.paths import KB_DIR

REPO = Path(__file__).resolve().parents[1]


def test_piped_craftc_output_keeps_long_lines_whole(tmp_path: Path) -> None:
    """``craftc validate`` piped: the bundle's full content hash sits on the line that names it."""
    env = {k: v for k, v in os.environ.items() if k != "COLUMNS"}
    craftc = Path(sys.executable).parent / "craftc"  # the console script setup installs
    done = subprocess.run([str(craftc), "validate", str(KB_DIR / "direct-llm")],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    line = next(ln for ln in done.stdout.splitlines() if ln.startswith("ok: "))
    assert len(line) > 80 and len(line.split()[-1]) == 64, done.stdout  # a whole sha256
