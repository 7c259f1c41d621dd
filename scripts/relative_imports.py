"""Codemod: absolute ``craft_e.*`` imports inside the package folders become relative imports.

Why: ``craft_e.runtime.x`` lives in ``runtime/x.py`` through setuptools' ``package-dir``
mapping, so an absolute import does not tell a reader which file it names; ``from ..kb.bundle
import load_bundle`` does, from the importing file's own folder (issue 13, item 8).

What it rewrites, in every ``.py`` file of the folders pyproject maps into ``craft_e``
(compiler/, runtime/, schemas/, prompts/, craft_e_pkg/): ``from craft_e.a.b import x`` (at module
level, under ``if TYPE_CHECKING:`` and inside functions) and ``import craft_e.a.b as z`` (into
``from ..a import b as z``). Only the module part of a statement changes: the imported names,
their layout and comments stay as written. Tests, benchmarks and scripts keep absolute imports
(they are not part of the package). A bare ``import craft_e.a.b`` (no ``as``) binds the name
``craft_e`` and has no relative form: it is reported and left alone.

Idempotent: relative imports are never touched, so a second run changes nothing and may follow
any merge. Afterwards it runs ``ruff check --fix --select I`` on the files it changed, because
relative imports sort into their own block.

Run: ``.venv/bin/python scripts/relative_imports.py [--check]`` (``--check``: change nothing,
exit 1 if a file would change).
"""

from __future__ import annotations

import argparse
import ast
import re
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOP = "craft_e"


def package_dirs(root: Path = ROOT) -> dict[str, Path]:
    """``craft_e.*`` package -> folder, read from pyproject's ``package-dir`` (the one source)."""
    config = tomllib.loads((root / "pyproject.toml").read_text(encoding="utf-8"))
    return {pkg: root / d for pkg, d in config["tool"]["setuptools"]["package-dir"].items()}


def module_files(root: Path = ROOT) -> dict[Path, str]:
    """Every module file of the distribution -> its dotted name (``__init__`` -> the package)."""
    dirs = package_dirs(root)
    mapped = {d.resolve() for d in dirs.values()}
    out: dict[Path, str] = {}
    for pkg, base in dirs.items():
        for f in sorted(base.rglob("*.py")):
            rel = f.relative_to(base)
            # a sub-folder that is itself mapped (none today) or a stray folder of the top package
            if any(p.resolve() in mapped for p in f.parents if p != base and p.is_relative_to(base)):
                continue
            if pkg == TOP and len(rel.parts) > 1:
                continue  # craft_e_pkg holds only top-level modules
            parts = list(rel.with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[f] = ".".join([pkg, *parts])
    return out


def relative_module(importer: str, is_package: bool, target: str) -> str:
    """``from <target>`` written relative to module ``importer``: dots, then the rest."""
    here = importer.split(".") if is_package else importer.split(".")[:-1]
    there = target.split(".")
    common = 0
    while common < min(len(here), len(there)) and here[common] == there[common]:
        common += 1
    if common == 0:
        raise ValueError(f"{target} is outside {importer}'s package tree")
    dots = "." * (len(here) - common + 1)
    return dots + ".".join(there[common:])


@dataclass(frozen=True)
class Edit:
    """Replace ``old`` (the start of the statement's source) with ``new`` at 1-based ``line``."""

    line: int
    col: int
    old: str
    new: str


_FROM = re.compile(r"from\s+(craft_e(?:\.[A-Za-z_][\w]*)*)\s+import\b")
_IMPORT_AS = re.compile(r"import\s+(craft_e(?:\.[A-Za-z_][\w]*)+)\s+as\s+([A-Za-z_]\w*)\s*$")


def plan(source: str, module: str, is_package: bool) -> tuple[list[Edit], list[str]]:
    """The edits that make ``source``'s absolute ``craft_e`` imports relative, and the
    statements left alone (with why)."""
    lines = source.splitlines(keepends=True)
    edits: list[Edit] = []
    skipped: list[str] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module is not None and (
                node.module == TOP or node.module.startswith(TOP + ".")):
            text = lines[node.lineno - 1][node.col_offset:]
            m = _FROM.match(text)
            if m is None or m.group(1) != node.module:
                skipped.append(f"{node.lineno}: unusual layout, left alone")
                continue
            new = f"from {relative_module(module, is_package, node.module)} import"
            edits.append(Edit(node.lineno, node.col_offset, m.group(0), new))
        elif isinstance(node, ast.Import) and any(
                a.name == TOP or a.name.startswith(TOP + ".") for a in node.names):
            segment = ast.get_source_segment(source, node) or ""
            m = _IMPORT_AS.match(segment)
            if len(node.names) != 1 or m is None or node.end_lineno != node.lineno:
                skipped.append(f"{node.lineno}: `{segment}` has no relative form, left alone")
                continue
            parent, _, leaf = m.group(1).rpartition(".")
            new = f"from {relative_module(module, is_package, parent)} import {leaf} as {m.group(2)}"
            edits.append(Edit(node.lineno, node.col_offset, m.group(0), new))
    return edits, skipped


def apply(source: str, edits: list[Edit]) -> str:
    lines = source.splitlines(keepends=True)
    for e in sorted(edits, key=lambda e: (e.line, e.col), reverse=True):
        line = lines[e.line - 1]
        assert line[e.col:e.col + len(e.old)] == e.old, (e.line, line)
        lines[e.line - 1] = line[:e.col] + e.new + line[e.col + len(e.old):]
    return "".join(lines)


def rewrite(path: Path, module: str) -> tuple[str | None, list[str]]:
    """The new text of ``path`` (None when nothing changes) and the statements left alone."""
    source = path.read_text(encoding="utf-8")
    edits, skipped = plan(source, module, path.name == "__init__.py")
    if not edits:
        return None, skipped
    new = apply(source, edits)
    ast.parse(new)  # still Python
    return new, skipped


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 if a file would change")
    parser.add_argument("--root", type=Path, default=ROOT, help="checkout to rewrite (default: this one)")
    args = parser.parse_args(argv)
    changed: list[Path] = []
    for path, module in module_files(args.root).items():
        new, skipped = rewrite(path, module)
        for s in skipped:
            print(f"{path.relative_to(args.root)}:{s}", file=sys.stderr)
        if new is None:
            continue
        changed.append(path)
        if not args.check:
            path.write_text(new, encoding="utf-8")
    if args.check:
        for p in changed:
            print(f"would rewrite {p.relative_to(args.root)}")
        return 1 if changed else 0
    if changed:
        ruff = Path(sys.executable).with_name("ruff")
        subprocess.run([str(ruff) if ruff.exists() else "ruff", "check", "--fix", "--quiet", "--select", "I",
                        *map(str, changed)], cwd=args.root, check=False)
    print(f"rewrote {len(changed)} files")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
