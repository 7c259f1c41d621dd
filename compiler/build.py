"""``craftc build``: the compiler's passes, in the order they run.

    read vocabularies -> source knowledge (LLM stages / ConceptNet / direct baseline, cache-first)
    -> overrides -> graph checks -> affordance energy -> embeddings -> emit bundle

Each pass counts what it read, kept and dropped (``report.json``). The same inputs give a
byte-identical bundle; volatile facts go to ``build_info.json`` outside the content hash.
"""

from __future__ import annotations

import io
import json
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from safetensors.numpy import save as save_safetensors

from .. import __version__
from ..runtime.encoders.text import MINILM_DIM, MINILM_ID, MINILM_SHA256
from ..runtime.grounding.energies import (
    FORBIDDEN_ENERGY,
    EnergyForm,
    affordance_energy_matrix,
)
from ..runtime.grounding.open_world import fit_open_world, open_world_json
from ..runtime.kb.diagnostics import diagnostics_model
from ..schemas.v1.bundle import (
    UNSEALED,
    BuildInfo,
    BundleReport,
    EnergyInfo,
    Manifest,
    TextEncoderInfo,
    sealed,
)
from .cache import RecordCache
from .draft import KnowledgeDraft
from .embed import EmbeddingCache
from .emit import check_out_path, file_digest, write_bundle
from .graph import build_graph, check_draft, coverage, graph_json, weight_matrices
from .llm_knowledge import (
    add_direct_paths,
    add_property_pass,
    direct_llm_draft,
    llm_property_draft,
)
from .object_colours import colours_json, recorded_colours
from .object_lookalikes import lookalikes_json, recorded_lookalikes
from .object_sizes import recorded_sizes, sizes_json
from .prompts import DEFAULT_PROMPT_VERSION
from .rdf import graph_turtle
from .sources.llm import LLMSource, Transport
from .vocab import Vocabulary, read_vocabulary

if TYPE_CHECKING:
    from .sources.batch import BatchLLMSource

KnowledgeMode = Literal["llm", "conceptnet", "direct", "llm+direct"]
VERB_TEMPLATE = "something to {verb}"


class BuildConfig(BaseModel):
    """Everything a build depends on (resolved once from the CLI, then passed in)."""

    model_config = ConfigDict(frozen=True)

    verbs_file: Path
    objects_file: Path
    out: Path
    # the manifest's rules, checked here so a bad name fails before the build's work, not after
    name: str = Field(pattern=r"^[a-z0-9][a-z0-9._-]*$")
    kb_version: str = Field(default="1.0.0", pattern=r"^\d+\.\d+\.\d+$")
    mode: KnowledgeMode = "llm"
    provider: str = "curated"
    model: str = "craft-e-curators"
    cache_root: Path
    overrides_file: Path | None = None
    conceptnet: str = "omcs"
    tau: float = Field(default=0.5, ge=0.0, le=1.0, allow_inf_nan=False)
    energy_form: EnergyForm = "sum-tanh"
    encoder_id: str = MINILM_ID
    force: bool = False
    prompt_version: Literal["v1", "v2"] = DEFAULT_PROMPT_VERSION
    property_pass: bool = False  # stage 2b: also ask per property over all objects (max w_po)
    # "ask": a per-object prompt for every pair no record covers; "reuse": read recorded
    # per-object answers only and leave the rest to stage 2b (needs property_pass)
    object_pass: Literal["ask", "reuse"] = "ask"
    concurrency: int = Field(default=4, ge=1)  # live synchronous requests in flight at once


@dataclass
class BuildResult:
    out: Path
    manifest: Manifest
    report: BundleReport
    notes: list[str]
    embedding_hits: int
    embedding_misses: int
    duration_s: float


Progress = Callable[[str, int], None]


def _source_pass(
    config: BuildConfig,
    verbs: Vocabulary,
    objects: Vocabulary,
    cache: RecordCache,
    transport: Transport | None,
    progress: Progress | None,
    batch: BatchLLMSource | None = None,
) -> KnowledgeDraft:
    if config.mode == "conceptnet":
        from .sources.conceptnet import conceptnet_draft

        return conceptnet_draft(verbs.names, objects.names, config.conceptnet, cache, progress)
    source = batch or LLMSource(
        cache=cache,
        provider=config.provider,
        model=config.model,
        transport=transport,
        max_concurrency=config.concurrency,
    )
    version, glosses, senses = config.prompt_version, objects.glosses, verbs.glosses
    if config.mode == "direct":
        return direct_llm_draft(
            source, verbs.names, objects.names, progress,
            version=version, glosses=glosses, verb_glosses=senses,
        )
    draft = llm_property_draft(
        source, verbs.names, objects.names, progress, version=version, glosses=glosses,
        verb_glosses=senses, ask_objects=config.object_pass == "ask",
    )
    if config.property_pass:
        add_property_pass(draft, source, progress)
    if config.mode == "llm+direct":
        direct = direct_llm_draft(
            source, verbs.names, objects.names, progress,
            version=version, glosses=glosses, verb_glosses=senses,
        )
        add_direct_paths(draft, direct)
    return draft


def _check_inputs(config: BuildConfig) -> None:
    """Read the overrides and local ConceptNet files' heads before the build's work.

    A wrong ``--overrides`` or ``--conceptnet csv:`` path must fail at once with an error that
    names it (exit 2), not after the knowledge passes, nor as a bare ``OSError`` that the CLI
    could only guess about.
    """
    if config.overrides_file is not None:
        from .sources.overrides import read_overrides_bytes

        read_overrides_bytes(config.overrides_file)
    if config.mode == "conceptnet":
        from .sources.conceptnet import check_spec

        check_spec(config.conceptnet)


def _overrides_pass(config: BuildConfig, draft: KnowledgeDraft) -> None:
    if config.overrides_file is not None:
        from .sources.overrides import apply_overrides

        apply_overrides(draft, config.overrides_file)


def _embeddings(
    config: BuildConfig, draft: KnowledgeDraft, properties: list[str], progress: Progress | None
) -> tuple[bytes, EmbeddingCache]:
    cache = EmbeddingCache(config.cache_root / "embeddings", config.encoder_id)
    tick = (lambda n: progress("embeddings", n)) if progress else None
    tensors = {
        "verb": cache.embed(draft.verbs, tick),  # [V, d]
        "verb_query": cache.embed([VERB_TEMPLATE.format(verb=v) for v in draft.verbs], tick),
        "object": cache.embed(draft.objects, tick),  # [O, d]
        "property": cache.embed(properties, tick)
        if properties
        else np.zeros((0, MINILM_DIM), np.float32),
    }
    index = {
        "encoder": config.encoder_id,
        "verbs": draft.verbs,
        "objects": draft.objects,
        "properties": properties,
        "verb_template": VERB_TEMPLATE,
    }
    # One metadata key only: safetensors stores metadata as a map whose order is not guaranteed.
    blob = save_safetensors(tensors, metadata={"index": json.dumps(index, sort_keys=True)})
    return blob, cache


#: ``progress`` stage names with this prefix announce a build phase (no count): the CLI shows each
#: phase as a line that completes when the next begins, so a replay build, which reads its
#: records without fetching any, still shows where it is
PHASE = "phase:"


def _phase(progress: Progress | None, name: str) -> None:
    if progress is not None:
        progress(PHASE + name, 0)


def build(
    config: BuildConfig,
    transport: Transport | None = None,
    progress: Progress | None = None,
    batch: BatchLLMSource | None = None,
) -> BuildResult:
    """Run every pass and emit the bundle at ``config.out`` (atomically).

    ``batch`` (``--provider openai-batch|gemini-batch``) answers each stage's missing records
    with one batch job instead of ``transport``'s synchronous calls.
    """
    started = time.perf_counter()
    # Refuse a destructive --out before any work (and again right before the swap).
    inputs: tuple[Path, ...] = (config.verbs_file, config.objects_file, config.cache_root)
    if config.overrides_file is not None:
        inputs += (config.overrides_file,)
    check_out_path(config.out, config.name, force=config.force, inputs=inputs)
    verbs = read_vocabulary(config.verbs_file, kind="verbs")
    objects = read_vocabulary(config.objects_file, kind="objects")
    _check_inputs(config)
    cache = RecordCache(config.cache_root)

    _phase(progress, "knowledge: records and passes")
    draft = _source_pass(config, verbs, objects, cache, transport, progress, batch)
    draft.count("read_vocabulary", "verbs", len(verbs.names))
    draft.count("read_vocabulary", "objects", len(objects.names))
    # names the reader changed or dropped; not blank lines, so re-spacing a vocabulary file does
    # not change the bundle's content hash
    draft.count("read_vocabulary", "normalization notes",
                sum(1 for n in (*verbs.notes, *objects.notes) if not n.endswith("blank line(s) ignored")))
    _overrides_pass(config, draft)
    check_draft(draft)

    _phase(progress, "graph and affordance energies")
    graph = build_graph(draft)
    properties = draft.properties()
    w_vp, w_po = weight_matrices(draft, properties)
    required = np.zeros(w_vp.shape, dtype=bool)  # [V, P] role "required" (prompt v2)
    p_index = {p: i for i, p in enumerate(properties)}
    for vi, verb in enumerate(draft.verbs):
        for prop, link in draft.verb_props.get(verb, {}).items():
            required[vi, p_index[prop]] = link.role == "required"
    energy = affordance_energy_matrix(
        w_vp, w_po, tau=config.tau, form=config.energy_form, required=required
    )  # [V, O]
    v_index = {v: i for i, v in enumerate(draft.verbs)}
    o_index = {o: i for i, o in enumerate(draft.objects)}
    for verb, obj in draft.forbidden:
        if verb in v_index and obj in o_index:
            energy[v_index[verb], o_index[obj]] = FORBIDDEN_ENERGY
    energy_buf = io.BytesIO()
    np.save(energy_buf, energy, allow_pickle=False)

    _phase(progress, "text embeddings")
    embeddings_blob, emb_cache = _embeddings(config, draft, properties, progress)
    # issue 11: the model that infers unseen objects' properties, fitted on this KB's objects
    from safetensors.numpy import load as load_safetensors

    _phase(progress, "open-world fit, sizes, colours, look-alikes")
    open_world = fit_open_world(load_safetensors(embeddings_blob)["object"], w_po, tau=config.tau)
    # perception knowledge: the objects' typical sizes, where a record gives one (never asked for)
    perception_source = LLMSource(cache=cache, provider=config.provider, model=config.model)
    sizes = recorded_sizes(perception_source, draft.objects, objects.glosses)
    draft.count("object_sizes", "objects with a typical size", len(sizes))
    colours = recorded_colours(perception_source, draft.objects, objects.glosses)
    draft.count("object_colours", "objects with typical colours", len(colours))
    lookalikes = recorded_lookalikes(perception_source, draft.objects, objects.glosses)
    draft.count("object_lookalikes", "objects with ImageNet look-alike classes", len(lookalikes))
    report = BundleReport(
        kb_name=config.name,
        counts={
            "verbs": len(draft.verbs),
            "objects": len(draft.objects),
            "properties": len(properties),
            "verb_property_edges": sum(len(p) for p in draft.verb_props.values()),
            "property_object_edges": graph.number_of_edges()
            - sum(len(p) for p in draft.verb_props.values()),
            "forbidden_pairs": len(draft.forbidden),
        },
        pass_counts={stage: dict(sorted(c.items())) for stage, c in sorted(draft.counters.items())},
        drops=sorted(draft.drops, key=lambda d: (d.stage, d.item, d.reason)),
        coverage=coverage(draft, energy),
        diagnostics=diagnostics_model(
            energy, w_vp, w_po, draft.verbs, properties, draft.objects, tau=config.tau
        ),
    )
    files = {
        "graph.json": graph_json(graph),
        "graph.ttl": graph_turtle(graph, config.name),
        "embeddings.safetensors": embeddings_blob,
        "affordance_energy.npy": energy_buf.getvalue(),
        "report.json": (
            json.dumps(report.model_dump(mode="json"), indent=1, sort_keys=True) + "\n"
        ).encode(),
        "open_world.json": open_world_json(open_world),
        "object_sizes.json": sizes_json(sizes, config.provider, config.model),
        "object_colours.json": colours_json(colours, config.provider, config.model),
        "object_lookalikes.json": lookalikes_json(lookalikes, config.provider, config.model),
    }
    digests = {name: file_digest(data) for name, data in files.items()}
    manifest = Manifest(
        kb_name=config.name,
        kb_version=config.kb_version,
        content_sha256=UNSEALED,
        files=digests,
        sources=draft.sources,
        text_encoder=TextEncoderInfo(
            id=config.encoder_id,
            weights_sha256=MINILM_SHA256,
            dim=MINILM_DIM,
            verb_template=VERB_TEMPLATE,
        ),
        energy=EnergyInfo(form=config.energy_form, tau=config.tau),
        verbs=draft.verbs,
        objects=draft.objects,
        properties=properties,
    )
    manifest = sealed(manifest)
    duration = time.perf_counter() - started
    info = BuildInfo(
        created_at=datetime.now(UTC).isoformat(timespec="seconds"),
        host=platform.node(),
        craft_e_version=__version__,
        duration_s=round(duration, 3),
        argv=sys.argv,
    )
    _phase(progress, "writing and verifying the bundle")
    write_bundle(config.out, files, manifest, info, force=config.force)
    unused = [] if config.prompt_version != "v1" or config.mode == "conceptnet" else [
        f"{config.verbs_file if kind == 'verb' else config.objects_file}: {n} {kind} gloss(es) not used: "
        "the v1 prompts carry no senses (--prompts v2 asks in them)"
        for kind, n in (("verb", len(verbs.glosses)), ("object", len(objects.glosses))) if n]
    return BuildResult(
        config.out,
        manifest,
        report,
        verbs.notes + objects.notes + unused,
        emb_cache.hits,
        emb_cache.misses,
        duration,
    )
