"""Bundle v1: the files of ``artifacts/kb/<name>/`` and the manifest that makes them verifiable.

``content_sha256`` is the sha256 of the canonical JSON of the manifest without that field; the
manifest's ``files`` table holds the sha256 of every bundle file but ``manifest.json`` and
``build_info.json``. Volatile
facts (time, host, durations) live in ``build_info.json`` so two builds of the same inputs are
byte-identical.
"""

from __future__ import annotations

import hashlib
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from .records import canonical_json

MANIFEST_SCHEMA_ID = "https://craft-e.dev/schemas/v1/manifest.json"

#: Files whose digests the manifest lists (hashed into ``content_sha256``).
BUNDLE_FILES: tuple[str, ...] = (
    "graph.json",
    "graph.ttl",
    "embeddings.safetensors",
    "affordance_energy.npy",
    "report.json",
    "open_world.json",
    "object_sizes.json",
    "object_colours.json",
    "object_lookalikes.json",
)
#: Bundle files a bundle built before they existed may lack (it still loads; the runtime then
#: goes without what the file provides). ``open_world.json``: issue 11's open-world model;
#: ``object_sizes.json`` / ``object_colours.json`` / ``object_lookalikes.json``: the objects' typical
#: sizes and colours and the ImageNet classes photos of them get (prompts ``object_size``,
#: ``object_colour``, ``object_lookalike``), for perception.
OPTIONAL_BUNDLE_FILES: tuple[str, ...] = ("open_world.json", "object_sizes.json", "object_colours.json",
                                          "object_lookalikes.json")


def listed_files_ok(listed: set[str] | frozenset[str]) -> bool:
    """Whether a manifest's file table is this schema's: every file, or every file but some
    optional ones (older bundles)."""
    required = set(BUNDLE_FILES) - set(OPTIONAL_BUNDLE_FILES)
    return required <= listed <= set(BUNDLE_FILES)


MANIFEST_FILE = "manifest.json"
BUILD_INFO_FILE = "build_info.json"


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FileDigest(_Frozen):
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    bytes: int = Field(ge=0)


class SourceInfo(_Frozen):
    """One knowledge source that fed the graph."""

    kind: Literal["llm", "conceptnet", "overrides"]
    provider: str
    model: str = ""
    prompts: list[str] = Field(default_factory=list, description="prompt id@version used")
    records: int = Field(ge=0, description="records read from this source")


class TextEncoderInfo(_Frozen):
    """The embedding space of the bundle; the runtime refuses a different encoder."""

    id: str
    weights_sha256: str
    dim: int = Field(gt=0)
    verb_template: str = Field(description="text template the verb query is embedded through")


class EnergyInfo(_Frozen):
    """How ``affordance_energy.npy`` was computed."""

    form: Literal[
        "sum-tanh", "normalized-product", "specificity", "required-veto", "specificity-veto"
    ] = Field("sum-tanh", description="E_aff form (craft_e.runtime.grounding.energies.EnergyForm)")
    tau: float = Field(ge=0.0, le=1.0, description="w_po threshold for an edge to count")


class Manifest(_Frozen):
    schema_id: Literal["https://craft-e.dev/schemas/v1/manifest.json"] = (
        "https://craft-e.dev/schemas/v1/manifest.json"
    )
    schema_version: Literal[1] = 1
    kb_name: str = Field(pattern=r"^[a-z0-9][a-z0-9._-]*$")
    kb_version: str = Field(pattern=r"^\d+\.\d+\.\d+$")
    content_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    files: dict[str, FileDigest]
    sources: list[SourceInfo]
    text_encoder: TextEncoderInfo
    energy: EnergyInfo
    verbs: list[str] = Field(description="row order of the verb axis (E_aff rows, embeddings)")
    objects: list[str] = Field(description="column order of the object axis")
    properties: list[str] = Field(description="row order of property embeddings")


#: Placeholder for ``content_sha256`` before a manifest is sealed.
UNSEALED = "0" * 64


def content_hash(manifest: Manifest) -> str:
    """sha256 over the canonical JSON of the whole manifest except ``content_sha256``.

    The manifest's file table pins every file's bytes, and hashing the rest of the manifest too
    (axis order, encoder, energy form, sources) means no field can be edited unnoticed.
    """
    body = manifest.model_dump(mode="json")
    body.pop("content_sha256")
    return hashlib.sha256(canonical_json(body).encode()).hexdigest()


def sealed(manifest: Manifest) -> Manifest:
    """The manifest with ``content_sha256`` set to its content hash."""
    return manifest.model_copy(update={"content_sha256": content_hash(manifest)})


class DropRecord(_Frozen):
    """Something a compiler pass left out, and why (ConceptNet-style drop counting)."""

    stage: str
    item: str
    reason: str


class Coverage(_Frozen):
    verbs_with_fewer_than_k_properties: dict[str, int]
    objects_without_properties: list[str]
    objects_unreachable_from_any_verb: list[str]
    verbs_reaching_no_object: list[str]


class Hub(_Frozen):
    object: str
    top_k_share: float = Field(ge=0.0, le=1.0, description="share of verbs with it in their top k")


class Diagnostics(_Frozen):
    """Does E_aff discriminate? (``craft_e.runtime.kb.diagnostics``; issue 9.)"""

    affordant_share: float = Field(ge=0.0, le=1.0, description="verb x object cells with E_aff < 0")
    saturated_share: float = Field(ge=0.0, le=1.0, description="cells with E_aff <= -0.99")
    top_k: int = Field(ge=1, description="k of the top-k lists behind the hub shares")
    hubs: list[Hub] = Field(description="objects in the most verbs' top k, biggest first")
    max_hub_share: float = Field(ge=0.0, le=1.0)
    properties_reaching_no_object: list[str]
    margin_rank: int = Field(ge=1, description="margins compare the best object with this rank")
    margin_median: float
    margins: dict[str, float] = Field(
        description="per verb: E_aff of its margin_rank-th object minus that of its best"
    )


class BundleReport(_Frozen):
    schema_id: Literal["https://craft-e.dev/schemas/v1/report.json"] = (
        "https://craft-e.dev/schemas/v1/report.json"
    )
    kb_name: str
    counts: dict[str, int]
    pass_counts: dict[str, dict[str, int]] = Field(
        description="per compiler pass: named counters (read, kept, dropped: <reason>)"
    )
    drops: list[DropRecord]
    coverage: Coverage
    diagnostics: Diagnostics | None = Field(
        None, description="discrimination diagnostics of the bundle's E_aff (absent before v1.1)"
    )


class BuildInfo(BaseModel):
    """Volatile facts about one build; outside the content hash on purpose."""

    model_config = ConfigDict(extra="forbid")

    created_at: str
    host: str
    craft_e_version: str
    duration_s: float
    argv: list[str]
