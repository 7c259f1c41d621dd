"""Which LLM records builds still use: the input of ``craftc cache clean``.

A record is *referenced* when

* a bundle under the bundle roots (by default every shipped bundle, ``artifacts/kb/*``) names
  its key in ``graph.json`` provenance or in its perception knowledge (``object_sizes.json``,
  ``object_colours.json``, ``object_lookalikes.json``: a rebuild looks those records up and silently ships fewer sizes
  without them), or the record asks the same prompt@version about the
  same subject for the same provider and model as one that is named (a *sibling*: the planners
  may need it to cover that subject, e.g. a stage-2b answer over objects that gained no edge,
  which no provenance names but a rebuild reads), or
* a replay build of the given verbs/objects files in the given modes reads it: every record
  ``fetch_many`` returns, every record the stage-2 / 2b / direct planners count as covering an
  object, property or verb (a covering record that added no edge is still needed: without it
  the planner would ask a new prompt, and replay would fail), every key in the draft's
  provenance, and every size, colour and look-alike record the build looks up.

Only the ``llm`` source folder is cleaned; other record sources and cached embeddings are left
as they are.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..schemas.v1.records import Record
from .cache import MAX_RECORD_BYTES, CacheError, RecordCache
from .draft import KnowledgeDraft
from .llm_knowledge import (
    add_property_pass,
    direct_llm_draft,
    llm_property_draft,
    plan_direct_calls,
    plan_object_calls,
    plan_property_calls,
)
from .object_colours import recorded_colours
from .object_lookalikes import recorded_lookalikes
from .object_sizes import recorded_sizes
from .sources.llm import LLMSource, PromptCall
from .vocab import read_vocabulary

_KEY = re.compile(r"^[0-9a-f]{64}$")
CLEAN_MODES = ("llm", "direct", "llm+direct")


class ReferencesError(ValueError):
    """The references could not be determined (a bundle unreadable, no referencing input)."""


def check_modes(modes: Sequence[str]) -> None:
    """``ReferencesError`` naming the first mode that is none of ``CLEAN_MODES``. ``craftc cache
    clean`` checks ``--mode`` before anything else: without ``--verbs`` the modes were never read,
    so a typo passed silently."""
    for mode in modes:
        if mode not in CLEAN_MODES:
            raise ReferencesError(f"--mode {mode!r}: unknown mode; choose from {', '.join(CLEAN_MODES)} "
                                  "(repeatable); nothing deleted")


#: bundle files whose ``objects`` name the record each answer came from
PERCEPTION_FILES = ("object_sizes.json", "object_colours.json", "object_lookalikes.json")


def bundle_references(roots: Iterable[Path], *, strict: bool = True) -> tuple[set[str], list[Path]]:
    """Record keys named by every bundle under ``roots``: ``graph.json`` provenance and the
    records of its perception knowledge (``PERCEPTION_FILES``).

    A root is a bundle folder or a folder of bundles. ``strict`` (roots the user named): a root
    that does not exist is an error, since a mistyped path must not leave its bundle's records
    unprotected; otherwise (the default root) it adds nothing. An existing folder without
    bundles adds nothing (the caller refuses to clean when nothing references a record).
    Returns (keys, graph files read).
    """
    keys: set[str] = set()
    graphs: list[Path] = []
    for root in roots:
        if not root.is_dir() and not strict:
            continue
        if not root.is_dir():
            raise ReferencesError(f"{root}: no such bundle folder (--bundles); check the path; nothing deleted")
        candidates = [root / "graph.json"] if (root / "graph.json").is_file() else sorted(
            root.glob("*/graph.json")
        )
        for path in candidates:
            _collect(_read_json(path, "bundle graph"), keys)
            for name in PERCEPTION_FILES:
                extra = path.parent / name
                if extra.is_file():
                    _collect_records(_read_json(extra, name), keys)
            graphs.append(path)
    return keys, graphs


def _read_json(path: Path, what: str) -> Any:
    try:
        if path.stat().st_size > 16 * MAX_RECORD_BYTES:
            raise ReferencesError(f"{path}: too large to be a {what}")
        return json.loads(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise ReferencesError(f"{path}: unreadable {what} ({exc}); nothing deleted") from None


def _collect_records(data: Any, keys: set[str]) -> None:
    """The ``record`` key of each answer in a perception file's ``objects``."""
    objects = data.get("objects") if isinstance(data, dict) else None
    for entry in objects.values() if isinstance(objects, dict) else []:
        key = entry.get("record") if isinstance(entry, dict) else None
        if isinstance(key, str) and _KEY.match(key):
            keys.add(key)


def _collect(data: Any, keys: set[str]) -> None:
    if not isinstance(data, dict):
        return
    items: list[Any] = []
    for name in ("edges", "links", "nodes"):
        value = data.get(name)
        if isinstance(value, list):
            items.extend(value)
    for item in items:
        if isinstance(item, dict):
            for key in item.get("provenance", []) or []:
                if isinstance(key, str) and _KEY.match(key):
                    keys.add(key)


@dataclass
class _TrackingSource(LLMSource):
    """A replay source that remembers the key of every record it hands out."""

    seen: set[str] = field(default_factory=set)

    def fetch_many(
        self, calls: Sequence[PromptCall], on_done: Callable[[PromptCall], None] | None = None
    ) -> list[Record]:
        records = super().fetch_many(calls, on_done)
        self.seen.update(r.key for r in records)
        return records


def _draft_keys(draft: KnowledgeDraft) -> set[str]:
    links = [*(link for p in draft.verb_props.values() for link in p.values()),
             *(link for o in draft.prop_objs.values() for link in o.values())]
    return {k for link in links for k in link.provenance if _KEY.match(k)}


def build_references(
    cache: RecordCache,
    verbs_file: Path,
    objects_file: Path,
    modes: Sequence[str],
    *,
    provider: str = "curated",
    model: str = "craft-e-curators",
    prompt_version: str = "v2",
    property_pass: bool = False,
) -> set[str]:
    """Keys of every record a replay build of these inputs reads (``MissingRecordError`` if one
    is missing: then the build's references cannot be known and nothing may be deleted)."""
    check_modes(modes)  # every mode before the work of any
    verb_vocab = read_vocabulary(verbs_file, kind="verbs")
    verbs, senses = verb_vocab.names, verb_vocab.glosses
    vocab = read_vocabulary(objects_file, kind="objects")
    objects, glosses = vocab.names, vocab.glosses
    source = _TrackingSource(cache=cache, provider=provider, model=model)
    keys: set[str] = set()
    for mode in modes:
        if mode in ("llm", "llm+direct"):
            draft = llm_property_draft(
                source, verbs, objects, version=prompt_version, glosses=glosses, verb_glosses=senses
            )
            covering, _ = plan_object_calls(
                source, objects, draft.properties(), version=prompt_version,
                glosses=draft.glosses, definitions=draft.definitions,
            )
            keys |= {r.key for records in covering.values() for r in records}
            if property_pass:
                covered, _ = plan_property_calls(
                    source, draft.properties(), draft.definitions, draft.objects, draft.glosses
                )
                keys |= {r.key for records in covered.values() for r in records}
                add_property_pass(draft, source)
            keys |= _draft_keys(draft)
        if mode in ("direct", "llm+direct"):
            direct = direct_llm_draft(
                source, verbs, objects, version=prompt_version, glosses=glosses, verb_glosses=senses
            )
            keys |= _draft_keys(direct)
            if prompt_version != "v1":
                by_verb, _ = plan_direct_calls(source, verbs, objects, glosses, senses)
                keys |= {r.key for records in by_verb.values() for r in records}
    if modes:  # every build looks up the objects' sizes, colours and look-alikes (never asks for them)
        perception = LLMSource(cache=cache, provider=provider, model=model)
        keys |= {s.record_key for s in recorded_sizes(perception, objects, glosses).values()}
        keys |= {c.record_key for c in recorded_colours(perception, objects, glosses).values()}
        keys |= {a.record_key for a in recorded_lookalikes(perception, objects, glosses).values()}
    return keys | source.seen


def with_siblings(cache: RecordCache, keys: set[str]) -> set[str]:
    """``keys`` plus every ``llm`` record with the same provider, model, prompt and subject as
    one of them (the default protection of shipped bundles)."""
    from .sources.llm import LLM_SOURCE

    heads: dict[str, tuple[str, str, str, str]] = {}
    folder = cache.root / LLM_SOURCE
    for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        try:
            head = json.loads(path.read_bytes())["request"]
            heads[path.stem] = (str(head["provider"]), str(head["model"]), str(head["prompt"]),
                                str(head["subject"]))
        except (OSError, ValueError, KeyError, TypeError):
            continue
    named = {heads[k] for k in keys if k in heads}
    return keys | {k for k, head in heads.items() if head in named}


@dataclass
class CleanPlan:
    """What ``craftc cache clean`` keeps and would delete (``llm`` records only)."""

    kept: int
    drop: list[tuple[Path, str]]  # (file, "provider/model prompt subject=...")
    drop_bytes: int
    graphs: list[Path]


def plan_clean(cache: RecordCache, referenced: set[str], graphs: list[Path]) -> CleanPlan:
    from .sources.llm import LLM_SOURCE

    drop: list[tuple[Path, str]] = []
    kept = size = 0
    folder = cache.root / LLM_SOURCE
    for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        if path.stem in referenced:
            kept += 1
            continue
        try:
            head = json.loads(path.read_bytes())["request"]
            label = (f"{head['provider']}/{head['model']} {head['prompt']} "
                     f"subject={head['subject']!r}")
        except (OSError, ValueError, KeyError, TypeError):
            label = "unreadable record"
        size += path.stat().st_size
        drop.append((path, label))
    return CleanPlan(kept, drop, size, graphs)


__all__ = [
    "CacheError",
    "CleanPlan",
    "ReferencesError",
    "build_references",
    "bundle_references",
    "plan_clean",
]
