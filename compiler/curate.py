"""Storing hand-written answers as records under provider ``curated``.

No LLM API is reachable from the project's machines, so the shipped knowledge is written by
people for the project's own rendered prompts. This module renders the exact prompt each answer
replies to, validates the answer against the prompt's response schema, and stores it as a
record — the same record a live provider would have produced, under an honest provider id.
It never invents an answer: a prompt without a written answer stays missing.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pydantic import ValidationError

from ..files import read_text_file
from ..schemas.names import normalize_name, normalize_property, normalize_verb
from ..schemas.v1.payloads import (
    ObjectColour,
    ObjectLookalikes,
    ObjectProperties,
    ObjectSize,
    PropertyObjects,
    VerbObjects,
    VerbProperties,
    VerbPropertiesV2,
)
from ..schemas.v1.records import Record
from .llm_knowledge import (
    direct_call,
    plan_direct_calls,
    plan_object_calls,
    plan_property_calls,
    read_verb_properties,
    verb_call,
)
from .object_colours import PROMPT_ID as COLOUR_PROMPT_ID
from .object_sizes import PROMPT_ID as SIZE_PROMPT_ID
from .per_object_prompts import LOOKALIKE_PROMPT_ID, pending_object_calls
from .prompts import DEFAULT_PROMPT_VERSION
from .sources.llm import LLM_SOURCE, LLMSource, PromptCall

#: Prompts asked once per object (perception knowledge) and the payload each answer must fit.
PER_OBJECT_PROMPTS: dict[str, type[ObjectSize] | type[ObjectColour] | type[ObjectLookalikes]] = {
    SIZE_PROMPT_ID: ObjectSize,
    COLOUR_PROMPT_ID: ObjectColour,
    LOOKALIKE_PROMPT_ID: ObjectLookalikes,
}


class CurationError(ValueError):
    """An answers file is malformed; the message names the file, the line and the fix."""


def _check_classes(answer: ObjectLookalikes, where: str) -> None:
    """Every class an ``object_lookalike`` answer names must be one the classifier can output."""
    import difflib

    from ..runtime.encoders.conse import imagenet_class_index

    known = imagenet_class_index()
    for entry in answer.classes:
        if entry.imagenet_class not in known:
            close = difflib.get_close_matches(entry.imagenet_class, list(known), n=3, cutoff=0.6)
            hint = f"did you mean {', '.join(repr(c) for c in close)}?" if close else (
                "write a name exactly as in runtime/encoders/imagenet_classes.txt")
            raise CurationError(f"{where}: {entry.imagenet_class!r} is not an ImageNet-1k class name; {hint}")


@dataclass
class CurationResult:
    stored: int
    unchanged: int
    skipped: list[str]
    #: answers not stored because their subject is in neither the verbs nor the objects file
    #: (also listed in ``skipped``); "already recorded" skips are not counted
    not_stored: int = 0


#: Every prompt ``record_answers`` stores answers to (``craftc curate record --prompt``).
PROMPT_IDS = ("verb_properties", "object_properties", "property_objects", "verb_objects", *PER_OBJECT_PROMPTS)


def read_answers(path: Path) -> list[tuple[int, dict[str, object]]]:
    """The answer objects of a JSONL file with their line numbers; a missing, unreadable,
    non-UTF-8 file or a folder is a ``CurationError`` naming it (``files.read_text_file``), and
    so is a file with no answer at all: "stored 0 records" and exit 0 would let a script believe
    an empty or truncated export had been recorded."""
    rows: list[tuple[int, dict[str, object]]] = []
    text = read_text_file(path, "answers file", CurationError)
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("//"):
            continue
        try:
            value = json.loads(line)
        except json.JSONDecodeError as exc:
            raise CurationError(
                f"{path}:{lineno}: not JSON ({exc.msg}); one answer object per line"
            ) from None
        if not isinstance(value, dict):
            raise CurationError(f"{path}:{lineno}: expected a JSON object")
        rows.append((lineno, value))
    if not rows:
        raise CurationError(f"{path}: no answers (the file is empty, or every line is blank or a // comment); "
                            "write one JSON answer object per line (nothing was stored)")
    return rows


def _record(source: LLMSource, call: PromptCall, payload: dict[str, object], note: str) -> Record:
    request = source.request_for(call)
    return Record(
        key=request.key(),
        source=LLM_SOURCE,
        request=request,
        raw_response=json.dumps(payload, ensure_ascii=False, sort_keys=True),
        payload=payload,
        note=note,
    )


def _conflict(existing: Record, record: Record) -> bool:
    """Does a stored record answer the same prompt differently? (Its note may differ.)"""
    return (existing.raw_response, existing.payload) != (record.raw_response, record.payload)


def record_answers(
    source: LLMSource,
    prompt_id: str,
    answers: Path,
    verbs: list[str],
    objects: list[str],
    note: str = "written by a CRAFT-E curator for this rendered prompt",
    *,
    version: str = DEFAULT_PROMPT_VERSION,
    glosses: dict[str, str] | None = None,
    verb_glosses: dict[str, str] | None = None,
    replace: bool = False,
) -> CurationResult:
    """Validate each answer in ``answers`` (JSONL) and store it as the record of its prompt.

    Every answer is checked before any is stored, so a bad line leaves the cache as it was. A
    stored answer is never rewritten: an answer to a prompt that already has a different one is an
    error (a new answer needs a new prompt or prompt version), unless ``replace`` (a scratch
    cache, e.g. a test simulating a provider that answered differently: the old answer is lost);
    two answers to one prompt in the file are an error. Skipped, and listed with the reason:
    answers about a verb, object or property the verbs / objects files do not name, and answers
    to prompts already recorded (not pending)."""
    if prompt_id not in PROMPT_IDS:
        raise CurationError(f"unknown prompt {prompt_id!r}; choose one of {', '.join(PROMPT_IDS)}")
    rows = read_answers(answers)  # before any record is read: a bad file fails first and fast
    result = CurationResult(0, 0, [])
    ready: list[tuple[str, Record]] = []
    unknown: list[str] = []  # answers about a subject the verbs / objects files do not name: skipped
    known_objects = set(objects)
    known_properties: set[str] = set()
    pending: dict[str, PromptCall] = {}
    senses = verb_glosses or {}
    if prompt_id == "object_properties":
        properties, definitions = _stage1_properties(source, verbs, version, senses)
        known_properties = set(properties)
        _, calls = plan_object_calls(
            source, objects, properties, version=version, glosses=glosses, definitions=definitions
        )
        pending = {c.subject: c for c in calls}
    elif prompt_id == "verb_objects" and version != "v1":
        _, calls = plan_direct_calls(source, verbs, objects, glosses or {}, senses)
        pending = {c.subject: c for c in calls}
    elif prompt_id == "property_objects":
        properties, definitions = _stage1_properties(source, verbs, version, senses)
        known_properties = set(properties)
        _, calls = plan_property_calls(source, properties, definitions, objects, glosses or {})
        pending = {c.subject: c for c in calls}
    elif prompt_id in PER_OBJECT_PROMPTS:
        pending = pending_object_calls(prompt_id, source, objects, glosses or {})
    for lineno, row in rows:
        where = f"{answers}:{lineno}"
        try:
            if prompt_id == "verb_properties" and version == "v1":
                vp = VerbProperties.model_validate(row)
                payload = vp.model_dump(mode="json")
                if normalize_verb(vp.verb) not in verbs:
                    unknown.append(f"{where}: {vp.verb!r} is not in the verbs file")
                    continue
                call = verb_call(normalize_verb(vp.verb), version=version)
                if len(vp.properties) != call.variables["k"]:
                    raise CurationError(
                        f"{where}: {vp.verb!r} has {len(vp.properties)} properties, the prompt asks for {call.variables['k']}"
                    )
            elif prompt_id == "verb_properties":
                vp2 = VerbPropertiesV2.model_validate(row)
                payload = vp2.model_dump(mode="json")
                verb = normalize_verb(vp2.verb)
                if verb not in verbs:
                    unknown.append(f"{where}: {vp2.verb!r} is not in the verbs file")
                    continue
                call = verb_call(verb, version=version, gloss=senses.get(verb, ""))
                if not 3 <= len(vp2.properties) <= call.variables["k"]:
                    raise CurationError(
                        f"{where}: {vp2.verb!r} has {len(vp2.properties)} properties, the prompt "
                        f"asks for 3 to {call.variables['k']}"
                    )
            elif prompt_id == "object_properties":
                op = ObjectProperties.model_validate(row)
                payload = op.model_dump(mode="json")
                obj = normalize_name(op.object)
                if obj not in known_objects:
                    unknown.append(f"{where}: {obj!r} is not in the objects file")
                    continue
                if obj not in pending:
                    result.skipped.append(f"{where}: {obj!r} has no pending request (already recorded)")
                    continue
                call = pending[obj]
                named = set(call.variables["properties"])
                outside = [
                    s.property for s in op.scores if normalize_property(s.property) not in named
                ]
                if outside:
                    raise CurationError(
                        f"{where}: {obj!r} scores properties outside the named set: {outside[:5]}"
                    )
            elif prompt_id == "property_objects":
                po = PropertyObjects.model_validate(row)
                payload = po.model_dump(mode="json")
                prop = normalize_property(po.property)
                if prop not in known_properties:
                    unknown.append(f"{where}: {prop!r} is not a property of the verbs file's stage-1 answers")
                    continue
                if prop not in pending:
                    result.skipped.append(f"{where}: {prop!r} has no pending request (already recorded)")
                    continue
                call = pending[prop]
                named = set(call.variables["objects"])
                outside = [s.object for s in po.scores if normalize_name(s.object) not in named]
                if outside:
                    raise CurationError(
                        f"{where}: {prop!r} scores objects outside the named set: {outside[:5]}"
                    )
            elif prompt_id == "verb_objects":
                vo = VerbObjects.model_validate(row)
                payload = vo.model_dump(mode="json")
                verb = normalize_verb(vo.verb)
                if version == "v1":
                    if verb not in verbs:
                        unknown.append(f"{where}: {vo.verb!r} is not in the verbs file")
                        continue
                    call = direct_call(verb, objects, version=version, glosses=glosses)
                else:  # v2 grows incrementally: the pending call names only uncovered objects
                    if verb not in verbs:
                        unknown.append(f"{where}: {vo.verb!r} is not in the verbs file")
                        continue
                    if verb not in pending:
                        result.skipped.append(
                            f"{where}: {verb!r} has no pending request (already recorded for every object)"
                        )
                        continue
                    call = pending[verb]
                offered = set(call.variables["objects"])
                outside = [r.object for r in vo.ranking if normalize_name(r.object) not in offered]
                if outside:
                    raise CurationError(
                        f"{where}: ranking names objects not offered: {outside[:5]}"
                    )
            elif prompt_id in PER_OBJECT_PROMPTS:
                answer = PER_OBJECT_PROMPTS[prompt_id].model_validate(row)
                if isinstance(answer, ObjectLookalikes):
                    _check_classes(answer, where)
                payload = answer.model_dump(mode="json")
                obj = normalize_name(str(answer.object), singularize=False)
                if obj not in known_objects and normalize_name(obj) not in known_objects:
                    unknown.append(f"{where}: {obj!r} is not in the objects file")
                    continue
                if obj not in pending:
                    result.skipped.append(f"{where}: {obj!r} has no pending {prompt_id} request (already recorded)")
                    continue
                call = pending[obj]
            else:
                raise CurationError(f"unknown prompt id {prompt_id!r}")
        except CurationError:
            raise
        except ValueError as exc:
            if not isinstance(exc, ValidationError):
                raise CurationError(f"{where}: {exc}; use plain lowercase names") from None
            first = exc.errors()[0]
            raise CurationError(
                f"{where}: {'.'.join(map(str, first['loc']))}: {first['msg']}"
            ) from None
        ready.append((where, _record(source, call, payload, note)))
    result.not_stored = len(unknown)
    result.skipped.extend(f"{line}: not stored (pass the --verbs / --objects file that names it)"
                          for line in unknown)
    first_line: dict[str, str] = {}
    for where, record in ready:
        if record.key in first_line:
            raise CurationError(
                f"{where}: answers the same prompt as {first_line[record.key]}; keep one answer per "
                "prompt (nothing was stored)"
            )
        first_line[record.key] = where
        existing = source.cache.get(LLM_SOURCE, record.key)
        if existing is not None and _conflict(existing, record) and not replace:
            raise CurationError(
                f"{where}: the prompt ({record.request.prompt} subject={record.request.subject!r}) "
                f"already has a different stored answer (record {record.key[:12]}...); stored "
                "answers are never rewritten: a new answer needs a new prompt or prompt version "
                "(nothing was stored)"
            )
    for _, record in ready:
        existing = source.cache.get(LLM_SOURCE, record.key)
        if existing is None or (replace and _conflict(existing, record)):
            source.cache.put(record)
            result.stored += 1
        else:
            result.unchanged += 1
    return result


def _stage1_properties(
    source: LLMSource, verbs: list[str], version: str, verb_glosses: dict[str, str] | None = None
) -> tuple[list[str], dict[str, str]]:
    """The stage-1 property names of ``verbs`` and (v2) their definitions, first one kept."""
    props: set[str] = set()
    definitions: dict[str, str] = {}
    for verb in verbs:
        record = source.fetch(
            verb_call(verb, version=version, gloss=(verb_glosses or {}).get(verb, ""))
        )
        for name, _, definition, _ in read_verb_properties(record, version):
            prop = normalize_property(name)
            props.add(prop)
            if definition:
                definitions.setdefault(prop, definition)
    return sorted(props), definitions


def pending_property_requests(
    source: LLMSource,
    verbs: list[str],
    objects: list[str],
    *,
    version: str = DEFAULT_PROMPT_VERSION,
    glosses: dict[str, str] | None = None,
    verb_glosses: dict[str, str] | None = None,
) -> list[dict[str, object]]:
    """Stage-2b prompts still to answer: property, definition, named object set, rendered prompt."""
    properties, definitions = _stage1_properties(source, verbs, version, verb_glosses)
    _, calls = plan_property_calls(source, properties, definitions, objects, glosses or {})
    return [
        {
            "property": c.subject,
            "definition": c.variables["definition"],
            "object_set_id": c.variables["object_set_id"],
            "objects": c.variables["objects"],
            "prompt": c.template.render(**c.variables)[1].content,
        }
        for c in calls
    ]


def pending_direct_requests(
    source: LLMSource,
    verbs: list[str],
    objects: list[str],
    *,
    version: str = DEFAULT_PROMPT_VERSION,
    glosses: dict[str, str] | None = None,
    verb_glosses: dict[str, str] | None = None,
) -> list[dict[str, object]]:
    """Direct (v2) prompts still to answer: verb, the objects no record covers, rendered prompt."""
    del version  # the direct prompt grows incrementally from v2 on
    _, calls = plan_direct_calls(source, verbs, objects, glosses or {}, verb_glosses)
    return [
        {
            "verb": c.subject,
            "objects": c.variables["objects"],
            "prompt": c.template.render(**c.variables)[1].content,
        }
        for c in calls
    ]


def pending_object_requests(
    source: LLMSource,
    verbs: list[str],
    objects: list[str],
    *,
    version: str = DEFAULT_PROMPT_VERSION,
    glosses: dict[str, str] | None = None,
    verb_glosses: dict[str, str] | None = None,
) -> list[dict[str, object]]:
    """What a curator still has to answer: object (+ gloss) + the named property set to score,
    and the exact rendered user message the answer replies to."""
    properties, definitions = _stage1_properties(source, verbs, version, verb_glosses)
    _, calls = plan_object_calls(
        source, objects, properties, version=version, glosses=glosses, definitions=definitions
    )
    return [
        {
            "object": c.subject,
            "gloss": c.variables.get("gloss", ""),
            "property_set_id": c.variables["property_set_id"],
            "properties": c.variables["properties"],
            "prompt": c.template.render(**c.variables)[1].content,
        }
        for c in calls
    ]


def pending_verb_requests(
    source: LLMSource,
    verbs: list[str],
    objects: list[str],
    *,
    version: str = DEFAULT_PROMPT_VERSION,
    glosses: dict[str, str] | None = None,
    verb_glosses: dict[str, str] | None = None,
) -> list[dict[str, object]]:
    """Stage-1 prompts still to answer: verb (+ the sense it is asked in) and rendered prompt."""
    del objects, glosses  # stage 1 names no objects
    senses = verb_glosses or {}
    calls = [verb_call(v, version=version, gloss=senses.get(v, "")) for v in verbs]
    return [
        {
            "verb": c.subject,
            "gloss": str(c.variables.get("verb_gloss", "")),
            "prompt": c.template.render(**c.variables)[1].content,
        }
        for c in calls
        if source.lookup(c) is None
    ]


def _pending_per_object_requests(
    prompt_id: str, source: LLMSource, objects: list[str], glosses: dict[str, str] | None
) -> list[dict[str, object]]:
    """``prompt_id`` prompts (one per object) still to answer: object, gloss, rendered prompt."""
    calls = pending_object_calls(prompt_id, source, objects, glosses or {})
    return [
        {
            "object": c.subject,
            "gloss": str(c.variables["gloss"]),
            "prompt": c.template.render(**c.variables)[1].content,
        }
        for c in calls.values()
    ]


def _per_object_lister(prompt_id: str, what: str) -> Callable[..., list[dict[str, object]]]:
    """A ``craftc curate pending`` lister for a per-object prompt (the CLI calls every lister
    with the same arguments; per-object prompts have one version and name no verbs)."""
    def lister(
        source: LLMSource,
        verbs: list[str],
        objects: list[str],
        *,
        version: str = DEFAULT_PROMPT_VERSION,
        glosses: dict[str, str] | None = None,
        verb_glosses: dict[str, str] | None = None,
    ) -> list[dict[str, object]]:
        del verbs, version, verb_glosses
        return _pending_per_object_requests(prompt_id, source, objects, glosses)

    lister.__doc__ = f"{what} prompts still to answer: object (+ gloss) and the rendered prompt."
    return lister


pending_size_requests = _per_object_lister(SIZE_PROMPT_ID, "Size")
pending_colour_requests = _per_object_lister(COLOUR_PROMPT_ID, "Colour")
pending_lookalike_requests = _per_object_lister(LOOKALIKE_PROMPT_ID, "Look-alike")
