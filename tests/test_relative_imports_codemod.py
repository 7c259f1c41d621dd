"""scripts/relative_imports.py: the codemod that keeps imports inside the package relative.

It must produce the relative form a reader can follow (and Python resolves to the same module),
leave what has no relative form alone, be idempotent (the coordinator re-runs it after merges),
and — checked on the real tree — leave no absolute ``craft_e`` import inside the package.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def codemod() -> ModuleType:
    spec = importlib.util.spec_from_file_location("relative_imports", ROOT / "scripts/relative_imports.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["relative_imports"] = module  # dataclasses look their module up while building
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules["relative_imports"]
    return module


def test_relative_module_counts_dots_from_the_importing_package(codemod: ModuleType) -> None:
    rel = codemod.relative_module
    assert rel("craft_e.runtime.grounding.grounder", False, "craft_e.runtime.kb.bundle") == "..kb.bundle"
    assert rel("craft_e.runtime.grounding.grounder", False, "craft_e.runtime.grounding.energies") == ".energies"
    assert rel("craft_e.runtime.grounding.grounder", False, "craft_e.schemas.v1") == "...schemas.v1"
    assert rel("craft_e.runtime.grounding.grounder", False, "craft_e") == "..."
    assert rel("craft_e.runtime.kb", True, "craft_e.runtime.kb.bundle") == ".bundle"  # an __init__
    assert rel("craft_e.paths", False, "craft_e.files") == ".files"
    with pytest.raises(ValueError, match="outside"):
        rel("craft_e.runtime.x", False, "numpy")


SOURCE = '''"""doc"""
from __future__ import annotations

from typing import TYPE_CHECKING

from craft_e.runtime.kb.bundle import (  # the loader
    Bundle,
    load_bundle,
)
from craft_e import paths
import craft_e.runtime.grounding.energies as en
import craft_e.runtime.kb

if TYPE_CHECKING:
    from craft_e.schemas.v1.graph import KnowledgeGraph


def f() -> None:
    from craft_e.runtime.grounding.settings import GroundingSettings
'''

EXPECTED = '''"""doc"""
from __future__ import annotations

from typing import TYPE_CHECKING

from ..kb.bundle import (  # the loader
    Bundle,
    load_bundle,
)
from ... import paths
from . import energies as en
import craft_e.runtime.kb

if TYPE_CHECKING:
    from ...schemas.v1.graph import KnowledgeGraph


def f() -> None:
    from .settings import GroundingSettings
'''


def test_rewrite_keeps_names_layout_and_comments_and_is_idempotent(codemod: ModuleType) -> None:
    module = "craft_e.runtime.grounding.grounder"
    edits, skipped = codemod.plan(SOURCE, module, False)
    new = codemod.apply(SOURCE, edits)
    assert new == EXPECTED
    assert len(skipped) == 1 and "import craft_e.runtime.kb" in skipped[0]  # no relative form
    again, _ = codemod.plan(new, module, False)
    assert again == []  # a second run changes nothing


def test_the_package_has_no_absolute_craft_e_imports_left(codemod: ModuleType) -> None:
    """After a merge adds absolute imports, run ``.venv/bin/python scripts/relative_imports.py``."""
    assert codemod.main(["--check"]) == 0
