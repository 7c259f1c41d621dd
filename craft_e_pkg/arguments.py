"""argparse types shared by the benchmark scripts: a bad count or output path fails at parse time,
naming the option, not minutes later as a traceback (or as a negative slice that quietly runs
everything)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from .files import output_file_problem


def positive_int(text: str) -> int:
    """An integer >= 1 (counts of scenes, episodes, repeats, pairs)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be at least 1")
    return value


def output_file(text: str) -> Path:
    """A file a script writes after minutes of work (--json, --markdown): checked before the work
    rather than as a traceback after it. The scripts do not create folders, so its folder must
    exist too."""
    path = Path(text)
    problem = output_file_problem(path)
    if problem is None and not path.parent.is_dir():
        problem = f"{path.parent} does not exist; create it or give another path"
    if problem is not None:
        raise argparse.ArgumentTypeError(problem)
    return path


def number_list(text: str) -> list[float]:
    """Comma-separated finite numbers >= 0 (weights such as --gammas)."""
    values = []
    for part in text.split(","):
        try:
            value = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{part!r} is not a number") from None
        if not math.isfinite(value) or value < 0:
            raise argparse.ArgumentTypeError(f"{part!r} must be a finite number >= 0")
        values.append(value)
    return values
