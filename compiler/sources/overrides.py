"""The overrides pass: a user's TOML file of edits, applied to the draft with provenance.

A KB author corrects what a source got wrong without touching records::

    [[add]]                      # verb -> property edge
    verb = "cut"
    property = "sharp edge"
    w_vp = 0.9

    [[add]]                      # property -> object edge
    property = "sharp edge"
    object = "knife"
    w_po = 1.0

    [[remove]]                   # an edge (either kind)
    property = "used for cut"
    object = "spoon"

    [[reweight]]                 # an edge's weight
    verb = "cut"
    property = "used for cut"
    w_vp = 0.6

    [[forbid]]                   # "never pick X for V"
    verb = "cut"
    object = "spoon"

Every edit names existing verbs/objects (and, except for adding a verb -> property edge,
existing properties), so a typo fails the build instead of silently doing nothing. Errors name
the file, the line of the table, the key and the fix. Edited edges get provenance
``override:<file name>:<line>`` and relation ``override``.
"""

from __future__ import annotations

import hashlib
import re
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ...schemas.names import normalize_name, normalize_property, normalize_verb
from ...schemas.v1.bundle import SourceInfo
from ..draft import KnowledgeDraft, Link

STAGE = "overrides"
EDIT_KINDS = ("add", "remove", "reweight", "forbid")
_WEIGHT_KEYS = {"w_vp", "w_po"}
_ALLOWED_KEYS = {
    "add": {"verb", "property", "object", "w_vp", "w_po", "note"},
    "remove": {"verb", "property", "object", "note"},
    "reweight": {"verb", "property", "object", "w_vp", "w_po", "note"},
    "forbid": {"verb", "object", "note"},
}
_EXAMPLE = {
    "add": "verb=..., property=..., w_vp=<0..1>  or  property=..., object=..., w_po=<0..1>",
    "remove": "verb=..., property=...  or  property=..., object=...",
    "reweight": "verb=..., property=..., w_vp=<0..1>  or  property=..., object=..., w_po=<0..1>",
    "forbid": "verb=..., object=...",
}


class OverridesError(ValueError):
    """An overrides file cannot be applied; the message names the file, line, key and fix."""


@dataclass(frozen=True)
class Edit:
    """One ``[[kind]]`` table of the file, with where it starts (for errors and provenance)."""

    kind: str
    index: int  # 0-based position among the tables of this kind
    line: int
    values: Mapping[str, Any]


@dataclass(frozen=True)
class Edge:
    """A resolved edge: ``verb -> property`` (``vp``) or ``property -> object`` (``po``)."""

    kind: str  # "vp" | "po"
    src: str
    dst: str

    def __str__(self) -> str:
        return f"{self.src} -> {self.dst}"


class _Locator:
    """Finds the line where each ``[[kind]]`` table (or key inside it) is written.

    ``tomllib`` gives values without positions, so the i-th ``[[add]]`` header in the text is
    matched to the i-th ``add`` table; inline arrays (``add = [{...}]``) fall back to the line of
    their key.
    """

    def __init__(self, text: str) -> None:
        self.lines = text.splitlines()
        self.headers: dict[str, list[int]] = {}
        header = re.compile(r"^\s*\[\[\s*([A-Za-z0-9_-]+)\s*\]\]")
        for lineno, line in enumerate(self.lines, start=1):
            found = header.match(line)
            if found:
                self.headers.setdefault(found.group(1), []).append(lineno)

    def table(self, kind: str, index: int) -> int:
        starts = self.headers.get(kind, [])
        if index < len(starts):
            return starts[index]
        return self.key(kind, 0, None) or 1

    def key(self, kind: str, start: int, stop: int | None) -> int | None:
        """First line in ``[start, stop)`` (1-based) that assigns ``kind``."""
        pattern = re.compile(rf"^\s*{re.escape(kind)}\s*=")
        end = stop if stop is not None else len(self.lines) + 1
        for lineno in range(max(start, 1), end):
            if pattern.match(self.lines[lineno - 1]):
                return lineno
        return None

    def key_in_table(self, edit: Edit, key: str) -> int:
        all_starts = sorted(n for starts in self.headers.values() for n in starts)
        stop = next((n for n in all_starts if n > edit.line), None)
        return self.key(key, edit.line + 1, stop) or edit.line


@dataclass
class _Applier:
    """Applies edits in file order, so a later table can use a property an earlier one added."""

    draft: KnowledgeDraft
    path: Path
    locator: _Locator

    def fail(self, edit: Edit, key: str | None, problem: str, fix: str) -> OverridesError:
        line = self.locator.key_in_table(edit, key) if key else edit.line
        where = f"[[{edit.kind}]] #{edit.index + 1}" + (f", key '{key}'" if key else "")
        return OverridesError(f"{self.path}:{line}: {where}: {problem}; {fix}")

    def provenance(self, edit: Edit) -> str:
        return f"override:{self.path.name}:{edit.line}"

    # -- validation ---------------------------------------------------------------------------

    def check_keys(self, edit: Edit) -> None:
        allowed = _ALLOWED_KEYS[edit.kind]
        for key, value in edit.values.items():
            if key not in allowed:
                raise self.fail(edit, key, "unknown key",
                                f"allowed keys: {', '.join(sorted(allowed))}")
            if key in _WEIGHT_KEYS:
                self.check_weight(edit, key, value)
            elif not isinstance(value, str):
                raise self.fail(edit, key, f"expected a string, got {type(value).__name__}",
                                f'write it in quotes, e.g. {key} = "..."')

    def check_weight(self, edit: Edit, key: str, value: Any) -> None:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(edit, key, f"expected a number, got {type(value).__name__}",
                            "write a weight between 0 and 1, e.g. 0.8")
        if not 0.0 <= float(value) <= 1.0:
            raise self.fail(edit, key, f"weight {value} out of range",
                            "use a number in [0, 1]")

    def name(self, edit: Edit, key: str, normalize: Callable[[str], str]) -> str:
        try:
            return normalize(edit.values[key])
        except ValueError as exc:
            raise self.fail(edit, key, str(exc), "use plain lowercase words") from None

    def verb(self, edit: Edit) -> str:
        verb = self.name(edit, "verb", normalize_verb)
        if verb not in self.draft.verbs:
            raise self.fail(edit, "verb", f"unknown verb {verb!r}",
                            "use a verb of the verbs file (or add it there)")
        return verb

    def object(self, edit: Edit) -> str:
        obj = self.name(edit, "object", normalize_name)
        if obj not in self.draft.objects:
            raise self.fail(edit, "object", f"unknown object {obj!r}",
                            "use an object of the objects file (or add it there)")
        return obj

    def known_property(self, edit: Edit) -> str:
        prop = self.name(edit, "property", normalize_property)
        if prop not in self.draft.properties() and prop not in self.draft.prop_objs:
            raise self.fail(edit, "property", f"unknown property {prop!r}",
                            "add it to a verb first ([[add]] verb=..., property=..., w_vp=...)")
        return prop

    def edge(self, edit: Edit, *, new_property: bool = False) -> Edge:
        """The edge a table names: exactly verb+property or property+object."""
        keys = set(edit.values) - {"note"} - _WEIGHT_KEYS
        if keys == {"verb", "property"}:
            verb = self.verb(edit)
            prop = (self.name(edit, "property", normalize_property) if new_property
                    else self.known_property(edit))
            return Edge("vp", verb, prop)
        if keys == {"property", "object"}:
            return Edge("po", self.known_property(edit), self.object(edit))
        raise self.fail(edit, None, f"names {', '.join(sorted(keys)) or 'nothing'}",
                        f"an edge is {_EXAMPLE[edit.kind]}")

    def weight(self, edit: Edit, edge: Edge) -> float:
        key = "w_vp" if edge.kind == "vp" else "w_po"
        other = "w_po" if edge.kind == "vp" else "w_vp"
        if other in edit.values:
            raise self.fail(edit, other, f"{other} does not belong to a {edge.kind} edge",
                            f"use {key} for {'verb -> property' if edge.kind == 'vp' else 'property -> object'}")
        if key not in edit.values:
            raise self.fail(edit, None, f"missing key '{key}'", f"add {key} = <0..1>")
        return float(edit.values[key])

    def table_of(self, edge: Edge) -> dict[str, Link]:
        store = self.draft.verb_props if edge.kind == "vp" else self.draft.prop_objs
        return store.setdefault(edge.src, {})

    # -- edits --------------------------------------------------------------------------------

    def apply(self, edit: Edit) -> None:
        self.check_keys(edit)
        {"add": self.add, "remove": self.remove, "reweight": self.reweight,
         "forbid": self.forbid}[edit.kind](edit)

    def add(self, edit: Edit) -> None:
        edge = self.edge(edit, new_property=True)
        weight = self.weight(edit, edge)
        links = self.table_of(edge)
        if edge.dst in links:
            raise self.fail(edit, None, f"edge {edge} already exists (weight "
                            f"{links[edge.dst].weight}, from {links[edge.dst].relation})",
                            "use [[reweight]] to change it")
        links[edge.dst] = Link(weight, (self.provenance(edit),), "override")
        self.draft.count(STAGE, f"added {edge.kind} edges")

    def remove(self, edit: Edit) -> None:
        edge = self.edge(edit)
        if any(k in edit.values for k in _WEIGHT_KEYS):
            raise self.fail(edit, None, "a removal takes no weight", "drop the w_vp/w_po key")
        links = self.table_of(edge)
        if edge.dst not in links:
            raise self.fail(edit, None, f"no edge {edge} to remove",
                            "check the names against the source's graph, or delete this table")
        del links[edge.dst]
        self.draft.drop(STAGE, str(edge), f"removed by override: {self.provenance(edit)}")

    def reweight(self, edit: Edit) -> None:
        edge = self.edge(edit)
        weight = self.weight(edit, edge)
        links = self.table_of(edge)
        old = links.get(edge.dst)
        if old is None:
            raise self.fail(edit, None, f"no edge {edge} to reweight", "use [[add]] to create it")
        # the answer's role (required / helpful) stays: a weight edit is not a judgment of necessity
        links[edge.dst] = Link(weight, (*old.provenance, self.provenance(edit)), "override", old.role)
        self.draft.count(STAGE, f"reweighted {edge.kind} edges")

    def forbid(self, edit: Edit) -> None:
        if set(edit.values) - {"note"} != {"verb", "object"}:
            raise self.fail(edit, None, "a forbid names a verb and an object",
                            f"write {_EXAMPLE['forbid']}")
        pair = (self.verb(edit), self.object(edit))
        self.draft.forbidden.add(pair)
        self.draft.count(STAGE, "forbidden pairs")


def read_edits(path: Path, text: str, locator: _Locator) -> list[Edit]:
    """Parse the TOML and list its tables in file order (by the line each one starts on)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        found = re.search(r"line (\d+)", str(exc))
        where = f"{path}:{found.group(1)}" if found else str(path)
        raise OverridesError(f"{where}: TOML syntax error: {exc}; fix the syntax "
                             f"(strings in quotes, one [[add]]/[[remove]]/... per edit)") from None
    edits: list[Edit] = []
    for kind, tables in data.items():
        line = locator.key(kind, 1, None) or (locator.headers.get(kind) or [1])[0]
        if kind not in EDIT_KINDS:
            raise OverridesError(f"{path}:{line}: unknown key '{kind}'; the file holds "
                                 f"[[add]], [[remove]], [[reweight]] and [[forbid]] tables")
        if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
            raise OverridesError(f"{path}:{line}: '{kind}' must be an array of tables; write "
                                 f"[[{kind}]] (double brackets) above each edit")
        edits.extend(Edit(kind, i, locator.table(kind, i), t) for i, t in enumerate(tables))
    return sorted(edits, key=lambda e: (e.line, EDIT_KINDS.index(e.kind), e.index))


def read_overrides_bytes(path: Path) -> bytes:
    """The bytes of the ``--overrides`` file; a missing file, a folder or an unreadable file is
    an :class:`OverridesError` naming it (a bare ``OSError`` would read as an output problem)."""
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise OverridesError(f"{path}: overrides file not found (--overrides)") from None
    except IsADirectoryError:
        raise OverridesError(
            f"{path}: is a folder; --overrides takes a TOML file of edits, e.g. edits.toml"
        ) from None
    except OSError as exc:
        raise OverridesError(
            f"{path}: cannot read the overrides file ({exc.strerror or exc}) (--overrides)"
        ) from None


def apply_overrides(draft: KnowledgeDraft, path: Path) -> KnowledgeDraft:
    """Apply the edits of ``path`` to ``draft`` in place (returned for chaining)."""
    data = read_overrides_bytes(path)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise OverridesError(f"{path}: not valid UTF-8; re-save the file as UTF-8") from None
    locator = _Locator(text)
    edits = read_edits(path, text, locator)
    applier = _Applier(draft, path, locator)
    for edit in edits:
        applier.apply(edit)
    draft.count(STAGE, "edits read", len(edits))
    draft.sources.append(SourceInfo(
        kind="overrides", provider="file", model=path.name,
        prompts=[f"{path.name}@sha256:{hashlib.sha256(data).hexdigest()}"], records=len(edits),
    ))
    return draft
