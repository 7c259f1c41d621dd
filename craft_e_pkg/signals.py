"""Process-wide signal handling shared by the ``craft`` and ``craftc`` console scripts."""

from __future__ import annotations

import signal


def exit_through_python_on_sigterm() -> None:
    """Make SIGTERM (CI cancelling a job, ``timeout``, ``kill``, systemd) exit like Ctrl-C does,
    through Python (status 143): atexit hooks, ``finally`` blocks and context managers run, so a
    build stopped while writing removes its hidden staging folder and the simulator's derived
    URDF folders are deleted, instead of being left on disk. Called once, when a command starts."""
    signal.signal(signal.SIGTERM, _exit)


def _exit(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)
