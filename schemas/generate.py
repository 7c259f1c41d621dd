"""Generate the JSON Schemas of every v1 artifact; committed copies live in ``schemas/v1/json``.

A test regenerates them and compares with the committed files, so a model change without a
schema regeneration fails CI (the dbt-core practice).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from .v1.bundle import BuildInfo, BundleReport, Manifest
from .v1.graph import KnowledgeGraph
from .v1.open_world import OpenWorld
from .v1.payloads import ObjectProperties, VerbObjects, VerbProperties
from .v1.records import Record

SCHEMA_DIR = Path(__file__).resolve().parent / "v1" / "json"
MODELS: dict[str, type[BaseModel]] = {
    "manifest": Manifest,
    "report": BundleReport,
    "build_info": BuildInfo,
    "graph": KnowledgeGraph,
    "open_world": OpenWorld,
    "record": Record,
    "verb_properties": VerbProperties,
    "object_properties": ObjectProperties,
    "verb_objects": VerbObjects,
}


def generate_all() -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for name, model in MODELS.items():
        schema = model.model_json_schema()
        schema["$id"] = f"https://craft-e.dev/schemas/v1/{name}.json"
        schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        out[name] = schema
    return out


def render(schema: dict[str, Any]) -> str:
    return json.dumps(schema, indent=2, sort_keys=True) + "\n"


def write_all() -> list[Path]:
    SCHEMA_DIR.mkdir(parents=True, exist_ok=True)
    written = []
    for name, schema in generate_all().items():
        path = SCHEMA_DIR / f"{name}.schema.json"
        path.write_text(render(schema), encoding="utf-8")
        written.append(path)
    return written
