"""The compiler's intermediate form: a weighted verb -> property -> object draft with provenance.

Every source pass (LLM, ConceptNet, direct-LLM baseline) produces a ``KnowledgeDraft``; the
overrides pass edits it; the graph pass turns it into the bundle's graph. Counters and drops are
kept per pass so ``report.json`` says what was read, kept and dropped, and why.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from ..schemas.v1.bundle import DropRecord, SourceInfo


@dataclass(frozen=True)
class Link:
    """One weighted edge and where it came from (record keys or override locations)."""

    weight: float
    provenance: tuple[str, ...]
    relation: str = "llm"
    role: str = ""  # verb -> property (prompt v2): "required" | "helpful"; "" = not given


@dataclass
class KnowledgeDraft:
    verbs: list[str]
    objects: list[str]
    verb_props: dict[str, dict[str, Link]] = field(default_factory=dict)  # verb -> prop -> w_vp
    prop_objs: dict[str, dict[str, Link]] = field(default_factory=dict)  # prop -> obj -> w_po
    forbidden: set[tuple[str, str]] = field(default_factory=set)  # (verb, object) never picked
    sources: list[SourceInfo] = field(default_factory=list)
    definitions: dict[str, str] = field(default_factory=dict)  # property -> one-line sense
    glosses: dict[str, str] = field(default_factory=dict)  # object -> sense it was asked in
    verb_glosses: dict[str, str] = field(default_factory=dict)  # verb -> sense it was asked in
    drops: list[DropRecord] = field(default_factory=list)
    counters: dict[str, Counter[str]] = field(default_factory=dict)

    def count(self, stage: str, what: str, n: int = 1) -> None:
        self.counters.setdefault(stage, Counter())[what] += n

    def drop(self, stage: str, item: str, reason: str) -> None:
        self.drops.append(DropRecord(stage=stage, item=item, reason=reason))
        self.count(stage, f"dropped: {reason.split(':')[0]}")

    def properties(self) -> list[str]:
        """Every property used by a verb, sorted."""
        return sorted({p for props in self.verb_props.values() for p in props})
