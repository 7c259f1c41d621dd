"""argparse types shared by the benchmark scripts: a bad count fails at parse time, naming the
option, not minutes later as a traceback (or as a negative slice that quietly runs everything)."""

from __future__ import annotations

import argparse


def positive_int(text: str) -> int:
    """An integer >= 1 (counts of scenes, episodes, repeats, pairs)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be at least 1")
    return value
