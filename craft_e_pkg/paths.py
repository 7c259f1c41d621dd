"""Where the project's data lives, from configuration — never from the location of the code.

The installed package carries everything it *is* (prompt templates, JSON Schemas, the sim
catalogue) as package data; everything it *works on* is found through configuration, so a wheel
installed outside a checkout behaves like the checkout:

* ``$CRAFT_ARTIFACTS`` — the artifacts folder (record cache, vocabularies, labels, bundles);
  default ``artifacts`` relative to the current directory, which is the checkout's own folder
  when a command runs from the repository root (as every script and README command does).
  ``KB_DIR``, ``VOCAB_DIR`` and ``LABELS_DIR`` are its ``kb/``, ``vocab/`` and ``labels/``.
* ``$CRAFT_CACHE`` — the record cache (``craftc --cache`` reads the same variable); default
  ``<artifacts>/cache``.
* ``$CRAFT_SHARED`` — the read-only reference data (models, images, ConceptNet); default
  ``../shared`` relative to the current directory (beside the checkout, run from its root).

Every command that reads one of these also takes an explicit option (``--cache``, ``--kb``,
``--objects``, ``--labels``, ...). The variables are read once, when this module is imported: set
them before starting a process.
"""

from __future__ import annotations

import os
from pathlib import Path


def _env_path(name: str, default: Path) -> Path:
    value = os.environ.get(name)
    return Path(value) if value else default


ARTIFACTS_DIR = _env_path("CRAFT_ARTIFACTS", Path("artifacts"))
CACHE_DIR = _env_path("CRAFT_CACHE", ARTIFACTS_DIR / "cache")
KB_DIR = ARTIFACTS_DIR / "kb"
VOCAB_DIR = ARTIFACTS_DIR / "vocab"
LABELS_DIR = ARTIFACTS_DIR / "labels"
SIM_DEV_LABELS = LABELS_DIR / "sim_dev_labels.csv"
#: the other 30 sim verbs, written after every default was chosen: a check, not for choosing
SIM_VAL_LABELS = LABELS_DIR / "sim_val_labels.csv"


def artifacts_hint(path: Path) -> str:
    """A sentence to append to a "not found" message about ``path``, or "": when ``path`` lies
    under the default ``artifacts`` folder, which is read from the current directory, and that
    folder is not a checkout's (it lacks the committed ``vocab/`` and ``labels/``), the command
    was run outside the checkout's root, and the message should say so. Whether ``path`` exists
    is the caller's to know; this only looks at where it was sought."""
    if os.environ.get("CRAFT_ARTIFACTS") or path.is_absolute() or ARTIFACTS_DIR.is_absolute():
        return ""
    if path.parts[: len(ARTIFACTS_DIR.parts)] != ARTIFACTS_DIR.parts:
        return ""
    if (ARTIFACTS_DIR / "vocab").is_dir() and (ARTIFACTS_DIR / "labels").is_dir():
        return ""  # the checkout's own folder: the path is missing from it, not sought elsewhere
    return (f" (`{ARTIFACTS_DIR}` is read from the current directory, {Path.cwd()}: run from the "
            "checkout's root, or set CRAFT_ARTIFACTS to its artifacts folder)")


def shared_dir() -> Path:
    """The shared reference folder: ``$CRAFT_SHARED`` or ``../shared`` (read at each call)."""
    env = os.environ.get("CRAFT_SHARED")
    return Path(env).resolve() if env else (Path.cwd().parent / "shared").resolve()


def existing_vocab_dir() -> Path:
    """VOCAB_DIR for the maintenance scripts that rewrite the checkout's vocabularies: run from
    anywhere else, the relative default would make a new ``artifacts/vocab`` in that folder."""
    if not VOCAB_DIR.is_dir():
        raise SystemExit(f"{VOCAB_DIR.resolve()}: no vocabulary folder here; run this script from the "
                         "checkout's root, or set CRAFT_ARTIFACTS to its artifacts folder")
    return VOCAB_DIR
