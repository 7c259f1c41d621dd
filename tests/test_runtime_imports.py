"""The import graph, read from the source of every module (no hand-picked list):

* the runtime never imports the compiler, httpx or rdflib — at module level *or* inside a
  function (robots ship without them);
* no two modules import each other, directly or in a ring (type-checking-only imports aside);
* and, dynamically, importing every runtime module loads none of them.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FORBIDDEN = ("craft_e.compiler", "httpx", "rdflib")


def package_dirs() -> dict[str, Path]:
    """``craft_e.*`` package -> folder, from pyproject's ``package-dir`` (the one source)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    return {pkg: ROOT / d for pkg, d in config["tool"]["setuptools"]["package-dir"].items()}


def modules() -> dict[str, Path]:
    """Every module of the distribution: dotted name -> file."""
    out: dict[str, Path] = {}
    for pkg, base in package_dirs().items():
        for f in sorted(base.rglob("*.py")):
            parts = list(f.relative_to(base).with_suffix("").parts)
            if pkg == "craft_e" and len(parts) > 1:
                continue  # craft_e_pkg holds only top-level modules
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join([pkg, *parts])] = f
    return out


def imported(name: str, source: str, known: set[str] | None = None) -> set[str]:
    """Modules ``source`` (module ``name``) imports anywhere, relative imports resolved;
    imports under ``if TYPE_CHECKING:`` are left out (they never run)."""
    is_pkg = known is not None and any(k.startswith(name + ".") for k in known)
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                for c in child.orelse:
                    visit(c)
                continue
            if isinstance(child, ast.Import):
                found.update(a.name for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = name.split(".")[: None if is_pkg else -1]
                    base = base[: len(base) - (child.level - 1)]
                    module = ".".join([*base, *([child.module] if child.module else [])])
                else:
                    module = child.module or ""
                found.add(module)
                found.update(f"{module}.{a.name}" for a in child.names
                             if known is not None and f"{module}.{a.name}" in known)
            visit(child)

    visit(ast.parse(source))
    return found


def forbidden(names: set[str]) -> list[str]:
    return sorted(n for n in names if n.split(".")[0] in FORBIDDEN or n.startswith(FORBIDDEN[0]))


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Rings of modules (strongly connected components with more than one module)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    rings: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            ring = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                ring.append(w)
                if w == v:
                    break
            if len(ring) > 1:
                rings.append(sorted(ring))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return rings


def test_the_scanner_sees_lazy_relative_and_guarded_imports() -> None:
    source = (
        "from typing import TYPE_CHECKING\n"
        "from ..compiler import build\n"
        "if TYPE_CHECKING:\n    import rdflib\n"
        "def f():\n    import httpx\n"
    )
    names = imported("craft_e.runtime.x", source)
    assert forbidden(names) == ["craft_e.compiler", "httpx"]  # rdflib is type-checking only
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_scanner_resolves_relative_imports_to_modules() -> None:
    """Inside the package imports are relative (scripts/relative_imports.py): each form must
    resolve to the module it names, or the no-compiler and no-cycle checks would see nothing."""
    known = {"craft_e.paths", "craft_e.runtime.kb", "craft_e.runtime.kb.bundle", "craft_e.runtime.grounding",
             "craft_e.runtime.grounding.energies", "craft_e.compiler", "craft_e.compiler.build"}
    source = (
        "from ..kb.bundle import load_bundle\n"  # a sibling package's module
        "from . import energies\n"  # a module of this package, named in the import list
        "from ... import paths\n"  # a top-level module
        "def f():\n    from ...compiler.build import build\n"  # lazy, and forbidden
    )
    names = imported("craft_e.runtime.grounding.grounder", source, known)
    assert {"craft_e.runtime.kb.bundle", "craft_e.runtime.grounding.energies", "craft_e.paths",
            "craft_e.compiler.build"} <= names
    assert forbidden(names) == ["craft_e.compiler.build"]
    # in a package's __init__, one dot is the package itself
    assert "craft_e.runtime.kb.bundle" in imported("craft_e.runtime.kb", "from .bundle import x\n", known)
    # a ring written with relative imports is still a ring
    graph = {m: {i for i in imported(m, src, known) if i in known and i != m} for m, src in (
        ("craft_e.runtime.kb.bundle", "from ..grounding import energies\n"),
        ("craft_e.runtime.grounding.energies", "from ..kb.bundle import Bundle\n"))}
    assert cycles(graph) == [["craft_e.runtime.grounding.energies", "craft_e.runtime.kb.bundle"]]


def test_runtime_source_imports_no_compiler_httpx_rdflib() -> None:
    mods = modules()
    runtime = {m: p for m, p in mods.items() if m.startswith("craft_e.runtime")}
    assert len(runtime) > 60  # the scan found the runtime, not an empty folder
    bad = {m: forbidden(imported(m, p.read_text(encoding="utf-8"), set(mods))) for m, p in runtime.items()}
    assert {m: b for m, b in bad.items() if b} == {}


def test_import_graph_has_no_cycles() -> None:
    mods = modules()
    graph = {m: {i for i in imported(m, p.read_text(encoding="utf-8"), set(mods)) if i in mods and i != m}
             for m, p in mods.items()}
    assert cycles(graph) == []


@pytest.mark.timeout(300)
def test_importing_every_runtime_module_loads_no_compiler() -> None:
    names = sorted(m for m in modules() if m.startswith("craft_e.runtime"))
    code = (
        "import importlib, json, sys\n"
        f"for name in {names!r}:\n"
        "    importlib.import_module(name)\n"
        f"bad = sorted(m for m in sys.modules if m.split('.')[0] in {FORBIDDEN!r} or m.startswith('craft_e.compiler'))\n"
        "print(json.dumps(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=240)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
