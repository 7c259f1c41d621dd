"""Where the project's own files and the shared reference data live.

The repository keeps prompts/ and artifacts/ beside the code (the design card's layout), so the
installed package finds them relative to the source tree; ``CRAFT_SHARED`` points at the read-only
``shared/`` folder (default: ``../shared`` next to the repository).
"""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
PROMPTS_DIR = REPO_ROOT / "prompts"
ARTIFACTS_DIR = REPO_ROOT / "artifacts"
CACHE_DIR = ARTIFACTS_DIR / "cache"
KB_DIR = ARTIFACTS_DIR / "kb"
VOCAB_DIR = ARTIFACTS_DIR / "vocab"


def shared_dir() -> Path:
    """The shared reference folder: ``$CRAFT_SHARED`` or ``<repo>/../shared``."""
    env = os.environ.get("CRAFT_SHARED")
    return Path(env).resolve() if env else (REPO_ROOT.parent / "shared").resolve()
