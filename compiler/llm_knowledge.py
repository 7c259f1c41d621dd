"""Source passes that turn LLM records into a draft: the paper's two stages + the direct baseline.

Stage 1 asks, per verb, for k properties with w_vp. Stage 2 asks, per object, for w_po over a
*named property set*. An object's existing records are reused for the properties they cover;
only properties no record covers go into a new, smaller request, so adding verbs never
invalidates what was already recorded.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable

from ..schemas.names import normalize_name, normalize_property
from ..schemas.v1.bundle import SourceInfo
from ..schemas.v1.payloads import (
    ObjectProperties,
    PropertyObjects,
    VerbObjects,
    VerbProperties,
    VerbPropertiesV2,
)
from ..schemas.v1.records import Record
from .draft import KnowledgeDraft, Link
from .graph import K_PROPERTIES
from .prompts import (
    DEFAULT_PROMPT_VERSION,
    format_glossed_list,
    format_list,
    load_prompt,
    property_set_id,
)
from .sources.llm import LLM_SOURCE, LLMSource, PromptCall

Progress = Callable[[str, int], None]
#: What the v2 object prompt says when a vocabulary entry carries no gloss.
NO_GLOSS = "its most common everyday sense"


#: Version of the verb prompts (stage 1, direct) for a verb meant in a stated sense: v2 plus the
#: verb's vocabulary gloss. Only glossed verbs are asked with it, so every unglossed verb keeps
#: its v2 record (a gloss on one verb never invalidates the others' answers).
SENSED_VERB_VERSION = "v3"


def verb_prompt_version(version: str, verb_gloss: str = "") -> str:
    """The template version a verb is asked with: v1 states no sense, so a gloss is ignored."""
    return SENSED_VERB_VERSION if verb_gloss and version != "v1" else version


def verb_call(
    verb: str, k: int = K_PROPERTIES, version: str = DEFAULT_PROMPT_VERSION, gloss: str = ""
) -> PromptCall:
    """Stage-1 call; a glossed verb (prompt v2) is asked with its sense (template v3)."""
    asked = verb_prompt_version(version, gloss)
    variables: dict[str, object] = {"verb": verb, "k": k}
    if asked == SENSED_VERB_VERSION:
        variables["verb_gloss"] = gloss
    return PromptCall(load_prompt("verb_properties", asked), verb, variables)


def object_call(
    obj: str,
    properties: list[str],
    *,
    version: str = DEFAULT_PROMPT_VERSION,
    gloss: str = "",
    definitions: dict[str, str] | None = None,
) -> PromptCall:
    """Stage-2 call: v1 names the property set; v2 also gives the object's sense and each
    property's definition (both part of the rendered prompt, hence of the record key)."""
    props = sorted(properties)
    if version == "v1":
        return PromptCall(
            load_prompt("object_properties", version),
            obj,
            {
                "object": obj,
                "properties": props,
                "property_list": format_list(props),
                "property_set_id": property_set_id(props),
            },
        )
    defs = definitions or {}
    listed = [f"{p}: {defs[p]}" if defs.get(p) else p for p in props]
    return PromptCall(
        load_prompt("object_properties", version),
        obj,
        {
            "object": obj,
            "gloss": gloss or NO_GLOSS,
            "properties": props,
            "property_list": format_list(listed),
            "property_set_id": property_set_id(listed),
        },
    )


def direct_call(
    verb: str,
    objects: list[str],
    *,
    version: str = DEFAULT_PROMPT_VERSION,
    glosses: dict[str, str] | None = None,
    verb_gloss: str = "",
) -> PromptCall:
    """Direct call; from v2 on objects are glossed, and a glossed verb is asked in its sense."""
    if version == "v1":
        return PromptCall(
            load_prompt("verb_objects", version),
            verb,
            {"verb": verb, "objects": sorted(objects), "object_list": format_list(objects)},
        )
    asked = verb_prompt_version(version, verb_gloss)
    variables: dict[str, object] = {
        "verb": verb,
        "objects": sorted(objects),
        "object_list": format_glossed_list(objects, glosses or {}),
    }
    if asked == SENSED_VERB_VERSION:
        variables["verb_gloss"] = verb_gloss
    return PromptCall(load_prompt("verb_objects", asked), verb, variables)


def records_by_prompt(
    source: LLMSource, prompt_refs: tuple[str, ...]
) -> dict[str, dict[str, list[Record]]]:
    """This provider/model's stored records of each prompt (``id@version``), by subject, read in
    one pass over the cache (a pass parses every record file: ~1.7 s for the shipped cache)."""
    index: dict[str, dict[str, list[Record]]] = {ref: defaultdict(list) for ref in prompt_refs}
    for _, record in source.cache.iter_records(LLM_SOURCE):
        req = record.request
        if req.prompt in index and req.provider == source.provider and req.model == source.model:
            index[req.prompt][req.subject].append(record)
    return index


def records_by_subject(source: LLMSource, prompt_ref: str) -> dict[str, list[Record]]:
    """This provider/model's stored records of one prompt (``id@version``), by subject."""
    return records_by_prompt(source, (prompt_ref,))[prompt_ref]


def index_object_records(source: LLMSource, version: str) -> dict[str, list[Record]]:
    """Existing object-property records of this provider/model/prompt version, by object.

    In v2 a record counts for an object only if it was asked in the same sense (gloss).
    """
    return records_by_subject(source, load_prompt("object_properties", version).ref)


def plan_object_calls(
    source: LLMSource,
    objects: list[str],
    properties: list[str],
    *,
    version: str = DEFAULT_PROMPT_VERSION,
    glosses: dict[str, str] | None = None,
    definitions: dict[str, str] | None = None,
) -> tuple[dict[str, list[Record]], list[PromptCall]]:
    """Which records cover each object, and the new calls needed for uncovered properties.

    (With ``object_pass="reuse"`` the build reads the covering records and drops the calls.)"""
    index = index_object_records(source, version)
    glosses = glosses or {}
    wanted = set(properties)
    covering: dict[str, list[Record]] = {}
    calls: list[PromptCall] = []
    for obj in objects:
        gloss = glosses.get(obj) or NO_GLOSS
        records = [
            r
            for r in index.get(obj, [])
            if wanted & set(r.request.variables["properties"])
            and (version == "v1" or r.request.variables.get("gloss") == gloss)
        ]
        covered = {p for r in records for p in r.request.variables["properties"]}
        missing = sorted(wanted - covered)
        covering[obj] = records
        if missing:
            calls.append(
                object_call(
                    obj, missing, version=version, gloss=gloss, definitions=definitions
                )
            )
    return covering, calls


PROPERTY_PROMPT_VERSION = "v1"


def property_call(
    prop: str, definition: str, objects: list[str], glosses: dict[str, str]
) -> PromptCall:
    """Stage-2b call: one property (with its definition) judged over a named, glossed object set.

    The glosses each object was shown with are kept in the variables, so a record counts for an
    object only while the object's sense is unchanged.
    """
    names = sorted(objects)
    listed = format_glossed_list(names, glosses)
    return PromptCall(
        load_prompt("property_objects", PROPERTY_PROMPT_VERSION),
        prop,
        {
            "property": prop,
            "definition": definition,
            "objects": names,
            "glosses": {o: glosses.get(o, "") for o in names},
            "object_list": listed,
            "object_set_id": "os-" + property_set_id(listed.splitlines())[3:],
        },
    )


def plan_property_calls(
    source: LLMSource,
    properties: list[str],
    definitions: dict[str, str],
    objects: list[str],
    glosses: dict[str, str],
) -> tuple[dict[str, list[Record]], list[PromptCall]]:
    """Which stage-2b records cover each property, and new calls for its uncovered objects.

    A record covers an object when it was asked with the same definition and the same gloss;
    adding objects therefore asks each property only about the new ones.
    """
    index = records_by_subject(source, load_prompt("property_objects", PROPERTY_PROMPT_VERSION).ref)
    covering: dict[str, list[Record]] = {}
    calls: list[PromptCall] = []
    for prop in properties:
        definition = definitions.get(prop, "")
        records = [
            r for r in index.get(prop, []) if r.request.variables.get("definition") == definition
        ]
        covered = {
            o
            for r in records
            for o, g in r.request.variables.get("glosses", {}).items()
            if g == glosses.get(o, "")
        }
        missing = [o for o in objects if o not in covered]
        covering[prop] = records
        if missing:
            calls.append(property_call(prop, definition, missing, glosses))
    return covering, calls


def add_property_pass(
    draft: KnowledgeDraft,
    source: LLMSource,
    progress: Progress | None = None,
) -> None:
    """Merge stage-2b answers (per property) into the per-object w_po: the larger weight wins.

    The per-object pass sees one object against ~200 properties and tends to miss some; the
    per-property pass sees one definition against every object and misses others. A pair either
    pass names with a weight counts, with the provenance of every record that named it.
    """
    stage = "stage2b_property_objects"
    properties = draft.properties()
    covering, calls = plan_property_calls(
        source, properties, draft.definitions, draft.objects, draft.glosses
    )
    records = source.fetch_many(calls, on_done=(lambda c: progress(stage, 1)) if progress else None)
    for call, record in zip(calls, records, strict=True):
        covering[call.subject].append(record)
    objects = set(draft.objects)
    read = 0
    for prop in properties:
        for record in sorted(covering[prop], key=lambda r: r.key):
            read += 1
            asked = {
                o
                for o, g in record.request.variables.get("glosses", {}).items()
                if g == draft.glosses.get(o, "")
            }
            answer = PropertyObjects.model_validate(record.payload)
            for score in answer.scores:
                obj = normalize_name(score.object)
                if obj not in asked or obj not in objects:
                    draft.drop(stage, f"{prop} -> {obj}", f"outside named set: record {record.key[:12]}")
                    continue
                links = draft.prop_objs.setdefault(prop, {})
                old = links.get(obj)
                if old is None:
                    links[obj] = Link(score.weight, (record.key,), "llm")
                    draft.count(stage, "edges added")
                elif score.weight > old.weight:
                    links[obj] = Link(score.weight, (*old.provenance, record.key), "llm")
                    draft.count(stage, "edges raised")
                else:
                    links[obj] = Link(old.weight, (*old.provenance, record.key), "llm")
                    draft.count(stage, "edges confirmed")
    draft.count(stage, "records read", read)
    draft.sources.append(
        SourceInfo(
            kind="llm",
            provider=source.provider,
            model=source.model,
            prompts=[load_prompt("property_objects", PROPERTY_PROMPT_VERSION).ref],
            records=read,
        )
    )


def read_verb_properties(
    record: Record, version: str
) -> list[tuple[str, float, str, str]]:
    """``(name, w_vp, definition, role)`` per property of a stage-1 record (v1: no definition,
    role "helpful")."""
    if version == "v1":
        v1 = VerbProperties.model_validate(record.payload)
        return [(p.name, p.weight, "", "helpful") for p in v1.properties]
    v2 = VerbPropertiesV2.model_validate(record.payload)
    return [(p.name, p.weight, p.definition.strip(), p.role) for p in v2.properties]


def llm_property_draft(
    source: LLMSource,
    verbs: list[str],
    objects: list[str],
    progress: Progress | None = None,
    *,
    version: str = DEFAULT_PROMPT_VERSION,
    glosses: dict[str, str] | None = None,
    verb_glosses: dict[str, str] | None = None,
    ask_objects: bool = True,
) -> KnowledgeDraft:
    """The paper's CRAFT-E KB: verb -> k properties -> objects, both stages from ``source``.

    ``ask_objects=False`` (``--object-pass reuse``) reads the recorded per-object answers but asks
    no new per-object prompt: pairs none covers are left to stage 2b, which judges one property
    against every object in one prompt (adding a verb then costs a prompt per new property, not
    one per object)."""
    draft = KnowledgeDraft(verbs=list(verbs), objects=list(objects))
    if version != "v1":  # v1 prompts did not state a sense: the graph must not claim one
        draft.glosses = {o: g for o, g in (glosses or {}).items() if o in set(objects)}
        draft.verb_glosses = {v: g for v, g in (verb_glosses or {}).items() if v in set(verbs)}
    stage1 = "stage1_verb_properties"
    verb_records = source.fetch_many(
        [verb_call(v, version=version, gloss=draft.verb_glosses.get(v, "")) for v in verbs],
        on_done=(lambda c: progress(stage1, 1)) if progress else None,
    )
    for verb, record in zip(verbs, verb_records, strict=True):
        draft.count(stage1, "records read")
        props = draft.verb_props.setdefault(verb, {})
        for raw_name, weight, definition, role in read_verb_properties(record, version):
            name = normalize_property(raw_name)
            if name in props:
                draft.drop(
                    stage1, f"{verb} -> {name}", "duplicate: property repeated after normalization"
                )
                continue
            known = draft.definitions.get(name)
            if definition and known is not None and known != definition:
                draft.drop(
                    stage1,
                    f"{verb} -> {name}",
                    f"conflicting definition: {name!r} is defined differently by another verb "
                    f"(record {record.key[:12]}); the first definition is kept",
                )
                continue
            if definition:
                draft.definitions[name] = definition
            props[name] = Link(weight, (record.key,), "llm", role=role if version != "v1" else "")
            draft.count(stage1, "edges kept")
            if version != "v1":
                draft.count(stage1, f"{role} properties")
        if len(props) < K_PROPERTIES:
            draft.count(stage1, "verbs with fewer than k properties")

    stage2 = "stage2_object_properties"
    properties = draft.properties()
    covering, new_calls = plan_object_calls(
        source,
        objects,
        properties,
        version=version,
        glosses=draft.glosses,
        definitions=draft.definitions,
    )
    if not ask_objects and new_calls:
        draft.count(stage2, "objects with properties left to stage 2b", len(new_calls))
        new_calls = []
    new_records = source.fetch_many(
        new_calls, on_done=(lambda c: progress(stage2, 1)) if progress else None
    )
    for call, record in zip(new_calls, new_records, strict=True):
        covering[call.subject].append(record)
    wanted = set(properties)
    used_records = 0
    for obj in objects:
        for record in sorted(covering[obj], key=lambda r: r.key):
            used_records += 1
            named = set(record.request.variables["properties"])
            answer = ObjectProperties.model_validate(record.payload)
            for score in answer.scores:
                prop = normalize_property(score.property)
                if prop not in named:
                    draft.drop(
                        stage2, f"{obj} -> {prop}", f"outside named set: record {record.key[:12]}"
                    )
                    continue
                if prop not in wanted:
                    draft.count(stage2, "scores for properties no verb uses")
                    continue
                links = draft.prop_objs.setdefault(prop, {})
                if obj in links:
                    draft.drop(
                        stage2,
                        f"{prop} -> {obj}",
                        f"duplicate: also scored by {links[obj].provenance[0][:12]}",
                    )
                    continue
                links[obj] = Link(score.weight, (record.key,), "llm")
                draft.count(stage2, "edges kept")
    draft.count(stage2, "records read", used_records)
    # How many of these records were fetched live *now* is a fact about the cache's history, not
    # about the knowledge: counting it in report.json (inside the content hash) made a cold and a
    # warm build of the same records differ, and two concurrent builds on one cache disagree.
    draft.sources.append(
        SourceInfo(
            kind="llm",
            provider=source.provider,
            model=source.model,
            prompts=[
                load_prompt("verb_properties", version).ref,
                *_sensed_refs("verb_properties", draft.verb_glosses),
                load_prompt("object_properties", version).ref,
            ],
            records=len(verb_records) + used_records,
        )
    )
    return draft


def direct_llm_draft(
    source: LLMSource,
    verbs: list[str],
    objects: list[str],
    progress: Progress | None = None,
    *,
    version: str = DEFAULT_PROMPT_VERSION,
    glosses: dict[str, str] | None = None,
    verb_glosses: dict[str, str] | None = None,
) -> KnowledgeDraft:
    """The direct-LLM baseline as a bundle: verb -> ``direct: <verb>`` -> ranked objects.

    One pseudo-property per verb (w_vp = 1) carries the model's confidence as w_po, so the
    same runtime and harness score it; objects the model left out get no edge.
    """
    draft = KnowledgeDraft(verbs=list(verbs), objects=list(objects))
    if version != "v1":
        draft.glosses = {o: g for o, g in (glosses or {}).items() if o in set(objects)}
        draft.verb_glosses = {v: g for v, g in (verb_glosses or {}).items() if v in set(verbs)}
    stage = "direct_verb_objects"
    vocabulary = set(objects)
    if version == "v1":
        records = source.fetch_many(
            [direct_call(v, objects, version=version, glosses=glosses) for v in verbs],
            on_done=(lambda c: progress(stage, 1)) if progress else None,
        )
        by_verb = {v: [r] for v, r in zip(verbs, records, strict=True)}
    else:
        by_verb, calls = plan_direct_calls(
            source, verbs, objects, glosses or {}, draft.verb_glosses
        )
        fetched = source.fetch_many(
            calls, on_done=(lambda c: progress(stage, 1)) if progress else None
        )
        for call, record in zip(calls, fetched, strict=True):
            by_verb[call.subject].append(record)
        records = [r for v in verbs for r in by_verb[v]]
    for verb in verbs:
        prop = f"direct: {verb}"
        keys = tuple(r.key for r in by_verb[verb])
        draft.verb_props[verb] = {prop: Link(1.0, keys, "direct")}
        links = draft.prop_objs.setdefault(prop, {})
        for record in by_verb[verb]:
            offered = set(offered_objects(record))
            payload = VerbObjects.model_validate(record.payload)
            for item in payload.ranking:
                obj = normalize_name(item.object)
                if obj not in offered:
                    draft.drop(stage, f"{verb} -> {obj}", "outside vocabulary: object not offered")
                    continue
                if obj not in vocabulary:
                    draft.count(stage, "offered in a wider record, not in this vocabulary")
                    continue
                if obj in links:
                    continue  # a later record about the same object in the same sense
                links[obj] = Link(item.score, (record.key,), "direct")
                draft.count(stage, "edges kept")
            draft.count(stage, "records read")
    draft.sources.append(
        SourceInfo(
            kind="llm",
            provider=source.provider,
            model=source.model,
            prompts=[
                load_prompt("verb_objects", version).ref,
                *_sensed_refs("verb_objects", draft.verb_glosses),
            ],
            records=len(records),
        )
    )
    return draft


def offered_objects(record: Record) -> dict[str, str]:
    """The objects a direct record offered, with the gloss each was shown with ('' if none)."""
    offered: dict[str, str] = {}
    for line in str(record.request.variables.get("object_list", "")).splitlines():
        name, _, gloss = line.removeprefix("- ").partition(": ")
        offered[name] = gloss
    return offered


def _sensed_refs(prompt_id: str, verb_glosses: dict[str, str]) -> list[str]:
    """The sensed template's ref when some verb was asked with it (unglossed KBs list none, so
    their manifests are unchanged)."""
    return [load_prompt(prompt_id, SENSED_VERB_VERSION).ref] if verb_glosses else []


def plan_direct_calls(
    source: LLMSource,
    verbs: list[str],
    objects: list[str],
    glosses: dict[str, str],
    verb_glosses: dict[str, str] | None = None,
) -> tuple[dict[str, list[Record]], list[PromptCall]]:
    """Direct (v2) records covering each verb's objects, and calls for the objects none covers.

    A record covers an object it offered in the same sense (gloss), so growing the vocabulary
    asks each verb only about the new objects; confidences are absolute, so answers about
    different object sets combine. A glossed verb is covered only by records asked in its sense.
    """
    verb_glosses = verb_glosses or {}
    plain_ref = load_prompt("verb_objects", "v2").ref
    sensed_ref = load_prompt("verb_objects", SENSED_VERB_VERSION).ref
    both = records_by_prompt(source, (plain_ref, sensed_ref))
    plain, sensed = both[plain_ref], both[sensed_ref]
    covering: dict[str, list[Record]] = {}
    calls: list[PromptCall] = []
    for verb in verbs:
        useful: list[Record] = []
        covered: set[str] = set()
        sense = verb_glosses.get(verb, "")
        candidates = (
            [r for r in sensed.get(verb, []) if r.request.variables.get("verb_gloss") == sense]
            if sense
            else plain.get(verb, [])
        )
        for record in sorted(candidates, key=lambda r: r.key):
            same_sense = {
                o for o, g in offered_objects(record).items() if g == glosses.get(o, "")
            } & set(objects)
            if same_sense - covered:
                useful.append(record)
                covered |= same_sense
        covering[verb] = useful
        missing = [o for o in objects if o not in covered]
        if missing:
            calls.append(
                direct_call(verb, missing, version="v2", glosses=glosses, verb_gloss=sense)
            )
    return covering, calls


DIRECT_PATH = "used to {verb}"


def add_direct_paths(draft: KnowledgeDraft, direct: KnowledgeDraft) -> None:
    """Add the direct answer as one more labelled path: verb -> "used to <verb>" -> object.

    The issue's option (mode ``llm+direct``): the objects a direct answer names for a verb
    become one helpful property of that verb (w_vp 1.0, w_po = the answer's confidence), so the
    property paths and the direct answer are scored together and every choice still says which
    path carried it.
    """
    stage = "direct_paths"
    for verb, props in direct.verb_props.items():
        for prop, link in props.items():
            name = DIRECT_PATH.format(verb=verb)
            draft.verb_props.setdefault(verb, {})[name] = Link(
                link.weight, link.provenance, "direct", role="helpful"
            )
            draft.definitions[name] = f"named by a direct answer to which objects afford {verb!r}"
            draft.prop_objs[name] = dict(direct.prop_objs.get(prop, {}))
            draft.count(stage, "edges kept", len(draft.prop_objs[name]))
    for counter_stage, counts in direct.counters.items():
        for what, n in counts.items():
            draft.count(counter_stage, what, n)
    draft.drops.extend(direct.drops)
    draft.sources.extend(direct.sources)
