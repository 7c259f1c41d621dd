"""Pass 2, rendering prompts: golden renderings (``prompts/*.expected.json``) and key identity.

A record answers one exact rendered prompt, so a template edit must show up (a new version file
and a different key), and a v1 rendering must never change under the records made for it.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import FIXTURES

from craft_e.compiler.cache import RecordCache
from craft_e.compiler.llm_knowledge import direct_call, object_call, verb_call
from craft_e.compiler.prompts import (
    PROMPTS_DIR,
    PromptError,
    format_list,
    load_prompt,
    property_set_id,
)
from craft_e.compiler.sources.llm import LLMSource, PromptCall

GOLDEN = {
    "verb_properties.v1.cut": verb_call("cut", version="v1"),
    "object_properties.v1.knife": object_call("knife", ["sharp edge", "has a handle", "concave"], version="v1"),
    "verb_objects.v1.scoop": direct_call("scoop", ["spoon", "knife", "bowl"], version="v1"),
}


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_rendering_matches_golden(name: str) -> None:
    expected = json.loads((FIXTURES / "prompts" / f"{name}.expected.json").read_text("utf-8"))
    call = GOLDEN[name]
    messages = [m.model_dump() for m in call.template.render(**call.variables)]
    assert call.template.ref == expected["prompt"]
    assert call.subject == expected["subject"]
    assert messages == expected["messages"], (
        f"{call.template.path} renders differently: a changed template needs a new version file"
    )


def test_rendering_does_not_depend_on_input_order() -> None:
    a = object_call("cup", ["waterproof", "concave", "has a handle"], version="v1")
    b = object_call("cup", ["has a handle", "waterproof", "concave"], version="v1")
    assert a.template.render(**a.variables) == b.template.render(**b.variables)
    assert a.variables["property_set_id"] == property_set_id(
        ["concave", "has a handle", "waterproof"]
    )
    assert format_list(["b", "a"]) == "- a\n- b"


def _source(tmp_path: Path) -> LLMSource:
    return LLMSource(RecordCache(tmp_path / "cache"), provider="test-fixture", model="fixture-v1")


def test_prompt_version_is_part_of_the_key(tmp_path: Path) -> None:
    prompts = tmp_path / "prompts"
    prompts.mkdir()
    v1 = PROMPTS_DIR / "verb_properties.v1.md"
    shutil.copy(v1, prompts / "verb_properties.v1.md")
    shutil.copy(v1, prompts / "verb_properties.v2.md")  # same text, new version
    edited = v1.read_text("utf-8").replace("descriptive properties", "visible properties")
    (prompts / "verb_properties.v3.md").write_text(edited, encoding="utf-8")
    source = _source(tmp_path)
    variables = {"verb": "cut", "k": 10}
    t1, t2, t3 = (load_prompt("verb_properties", v, prompts) for v in ("v1", "v2", "v3"))
    r1, r2, r3 = (source.request_for(PromptCall(t, "cut", variables)) for t in (t1, t2, t3))

    assert r1.prompt == "verb_properties@v1" and r2.prompt == "verb_properties@v2"
    assert r1.messages == r2.messages  # identical text ...
    assert r1.key() != r2.key()  # ... but the version alone changes the key
    assert r3.messages != r1.messages and r3.key() not in {r1.key(), r2.key()}
    # the shipped v1 template renders exactly like its copy: the key depends on content + ref
    assert source.request_for(verb_call("cut", version="v1")).key() == r1.key()


def test_key_covers_provider_model_params_and_variables(tmp_path: Path) -> None:
    source = _source(tmp_path)
    base = source.request_for(verb_call("cut", version="v1")).key()
    assert source.request_for(verb_call("cut", version="v1")).key() == base, "keys are stable"
    assert source.request_for(verb_call("scoop", version="v1")).key() != base
    assert source.request_for(verb_call("cut", k=5, version="v1")).key() != base
    other = LLMSource(source.cache, provider="other", model="fixture-v1")
    assert other.request_for(verb_call("cut", version="v1")).key() != base
    hot = LLMSource(
        source.cache, provider="test-fixture", model="fixture-v1", params={"temperature": 0.7}
    )
    assert hot.request_for(verb_call("cut", version="v1")).key() != base


def test_template_errors(tmp_path: Path) -> None:
    prompts = tmp_path / "prompts"
    prompts.mkdir()
    (prompts / "verb_properties.v9.md").write_text("## user\nonly a user part {verb}\n", "utf-8")
    (prompts / "verb_properties.v8.md").write_text(
        "## system\nsys\n## user\nneeds {missing}\n", "utf-8"
    )
    with pytest.raises(PromptError, match="needs exactly a '## system' and a '## user'"):
        load_prompt("verb_properties", "v9", prompts)
    with pytest.raises(PromptError, match="not found"):
        load_prompt("verb_properties", "v7", prompts)
    with pytest.raises(PromptError, match="unknown prompt id"):
        load_prompt("no_such_prompt", "v1", prompts)
    with pytest.raises(PromptError, match="unknown prompt id"):
        load_prompt("no_such_prompt")  # no version given: still a PromptError, not a KeyError
    template = load_prompt("verb_properties", "v8", prompts)
    with pytest.raises(PromptError, match="placeholder 'missing' has no value"):
        template.render(verb="cut")


@pytest.mark.parametrize("template", sorted(PROMPTS_DIR.glob("*.v*.md")), ids=lambda p: p.stem)
def test_the_response_schema_is_the_payloads_and_each_call_gets_its_own(template: Path) -> None:
    """The schema is made once per payload model (a warm rebuild asked pydantic for it 31,000
    times); it must stay pydantic's, key for key and in order, and a caller's edit must not leak."""
    prompt_id, version = template.stem.rsplit(".", 1)
    loaded = load_prompt(prompt_id, version)
    first = loaded.response_schema()
    assert json.dumps(first) == json.dumps(loaded.payload_model.model_json_schema())
    first["title"] = "edited"
    assert loaded.response_schema()["title"] != "edited"
