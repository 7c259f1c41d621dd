"""Artifact schemas: committed JSON Schemas match the models, versions are checked, names normalize.

The committed ``schemas/v1/json`` files are what external tools validate against; a model change
without regenerating them must fail here (the dbt-core practice), and an artifact of a newer
schema version must be refused with a message naming the file.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import jsonschema  # type: ignore[import-untyped]
import pytest
from conftest import FIXTURES, FixtureKB
from pydantic import ValidationError

from craft_e.runtime.kb.bundle import BundleError, load_bundle, read_manifest
from craft_e.schemas.generate import SCHEMA_DIR, generate_all, render
from craft_e.schemas.names import normalize_name, normalize_property, normalize_verb
from craft_e.schemas.v1.bundle import Manifest
from craft_e.schemas.v1.payloads import ObjectProperties, VerbProperties
from craft_e.schemas.v1.records import Record

NORMALIZERS = {"object": normalize_name, "verb": normalize_verb, "property": normalize_property}


def _name_cases() -> list[dict[str, str]]:
    lines = (FIXTURES / "names.jsonl").read_text(encoding="utf-8").splitlines()
    return [json.loads(line) for line in lines if line.strip() and not line.startswith("//")]


NAME_CASES = _name_cases()


# --- committed JSON Schemas ------------------------------------------------------------------


def test_committed_json_schemas_equal_a_fresh_generation() -> None:
    generated = generate_all()
    stale = [
        name
        for name, schema in generated.items()
        if not (SCHEMA_DIR / f"{name}.schema.json").is_file()
        or (SCHEMA_DIR / f"{name}.schema.json").read_text(encoding="utf-8") != render(schema)
    ]
    assert not stale, f"stale committed schemas {stale}: run `craftc schema --write` and commit"
    committed = {p.name.removesuffix(".schema.json") for p in SCHEMA_DIR.glob("*.schema.json")}
    assert committed == set(generated), "schemas/v1/json holds files no model generates"


def test_every_schema_has_an_id_and_a_dialect() -> None:
    for name, schema in generate_all().items():
        assert schema["$id"] == f"https://craft-e.dev/schemas/v1/{name}.json"
        assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
        jsonschema.Draft202012Validator.check_schema(schema)


def _committed(name: str) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((SCHEMA_DIR / f"{name}.schema.json").read_text("utf-8"))
    return data


def test_built_artifacts_validate_against_committed_schemas(kb_a: FixtureKB) -> None:
    for name, file in (
        ("manifest", "manifest.json"),
        ("report", "report.json"),
        ("build_info", "build_info.json"),
    ):
        instance = json.loads((kb_a.bundle / file).read_text("utf-8"))
        jsonschema.Draft202012Validator(_committed(name)).validate(instance)
    records = sorted((kb_a.cache / "llm").glob("*.json"))
    assert records
    for path in records:
        jsonschema.Draft202012Validator(_committed("record")).validate(
            json.loads(path.read_bytes())
        )


# --- versions --------------------------------------------------------------------------------


def _manifest_v2(kb_a: FixtureKB, tmp_path: Path) -> Path:
    import shutil

    folder = tmp_path / "bundle"
    shutil.copytree(kb_a.bundle, folder)
    path = folder / "manifest.json"
    data = json.loads(path.read_text("utf-8"))
    data["schema_version"] = 2
    path.write_text(json.dumps(data, indent=2), encoding="utf-8")
    return folder


def test_manifest_schema_version_2_is_refused_naming_the_file(
    kb_a: FixtureKB, tmp_path: Path
) -> None:
    folder = _manifest_v2(kb_a, tmp_path)
    with pytest.raises(BundleError) as info:
        read_manifest(folder)
    message = str(info.value)
    assert message.startswith(f"{folder / 'manifest.json'}: schema_version 2 is not supported")
    assert "rebuild" in message
    with pytest.raises(BundleError, match="schema_version 2"):
        load_bundle(folder, check_encoder=False)


def test_manifest_model_only_accepts_version_1(kb_a: FixtureKB) -> None:
    data = json.loads((kb_a.bundle / "manifest.json").read_text("utf-8"))
    assert Manifest.model_validate(data).schema_version == 1
    with pytest.raises(ValidationError):
        Manifest.model_validate({**data, "schema_version": 2})
    with pytest.raises(ValidationError):
        Manifest.model_validate({**data, "unexpected": True})


def test_record_rejects_unknown_fields_and_bad_keys(kb_a: FixtureKB) -> None:
    path = sorted((kb_a.cache / "llm").glob("*.json"))[0]
    data = json.loads(path.read_bytes())
    assert Record.model_validate(data).key == path.stem
    with pytest.raises(ValidationError):
        Record.model_validate({**data, "api_key": "sk-..."})
    with pytest.raises(ValidationError):
        Record.model_validate({**data, "key": "not-a-sha256"})


# --- payloads --------------------------------------------------------------------------------


def test_payloads_reject_duplicates_and_out_of_range_weights() -> None:
    ok = {"verb": "cut", "properties": [{"name": "sharp", "weight": 0.9}]}
    assert VerbProperties.model_validate(ok).properties[0].weight == 0.9
    with pytest.raises(ValidationError, match="unique"):
        VerbProperties.model_validate(
            {
                "verb": "cut",
                "properties": [{"name": "Sharp", "weight": 0.9}, {"name": "sharp", "weight": 0.5}],
            }
        )
    with pytest.raises(ValidationError):
        VerbProperties.model_validate({"verb": "cut", "properties": [{"name": "s", "weight": 1.5}]})
    with pytest.raises(ValidationError):
        VerbProperties.model_validate({"verb": "cut", "properties": []})
    assert ObjectProperties.model_validate({"object": "bowl", "scores": []}).scores == []
    with pytest.raises(ValidationError, match="once"):
        ObjectProperties.model_validate(
            {
                "object": "bowl",
                "scores": [
                    {"property": "round", "weight": 0.5},
                    {"property": "round", "weight": 0.6},
                ],
            }
        )


# --- names -----------------------------------------------------------------------------------


@pytest.mark.parametrize("case", NAME_CASES, ids=[f"{c['kind']}:{c['raw']!r}" for c in NAME_CASES])
def test_name_normalization_fixture_pairs(case: dict[str, str]) -> None:
    normalize = NORMALIZERS[case["kind"]]
    if "error" in case:
        with pytest.raises(ValueError, match=case["error"]):
            normalize(case["raw"])
    else:
        assert normalize(case["raw"]) == case["expected"]
        assert normalize(case["expected"]) == case["expected"], "normalization is idempotent"
