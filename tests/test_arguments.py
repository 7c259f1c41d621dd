"""``craft_e.arguments``: the benchmark scripts' count type."""

from __future__ import annotations

import argparse

import pytest

from craft_e.arguments import positive_int


def test_positive_int_accepts_counts_and_names_what_is_wrong() -> None:
    assert positive_int("3") == 3
    for text, message in (("0", "0 must be at least 1"), ("-1", "-1 must be at least 1"), ("x", "'x' is not")):
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            positive_int(text)
