"""Look-alike knowledge: object_lookalike records -> bundle's object_lookalikes.json -> ConSE's class
embeddings linked to the names whose photos get them. Fixture records use provider
``test-fixture`` (never ``curated``)."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import KB_SMALL, FixtureKB, _build, fixture_source
from pydantic import ValidationError

from craft_e.compiler.curate import CurationError, record_answers
from craft_e.compiler.per_object_prompts import (
    LOOKALIKE_PROMPT_ID,
    object_call,
    pending_object_calls,
)
from craft_e.compiler.vocab import read_vocabulary
from craft_e.paths import KB_DIR
from craft_e.runtime.encoders.conse import (
    ConSEImageEncoder,
    EncoderError,
    conse_embed,
    imagenet_class_names,
    link_class_embeddings,
)
from craft_e.runtime.encoders.lookalikes import LookalikesUnavailableError, linked_encoder
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import BundleError, load_bundle
from craft_e.runtime.kb.lookalikes import LookalikesError, parse_lookalikes
from craft_e.runtime.sim.pipeline import sim_vocabulary
from craft_e.schemas.v1.payloads import ObjectLookalikes


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def test_a_linked_class_moves_toward_the_name_by_its_share() -> None:
    rng = np.random.default_rng(0)
    classes = ["computer mouse", "crane", "banana", "crane"]  # two classes share a name, as in ImageNet
    emb = np.stack([_unit(rng.normal(size=8)) for _ in classes]).astype(np.float32)
    stapler, bird = _unit(rng.normal(size=8)), _unit(rng.normal(size=8))
    links = {"stapler": [("computer mouse", 0.4)], "heron": [("crane", 0.05)]}
    linked = link_class_embeddings(emb, classes, links, {"stapler": 3 * stapler, "heron": bird})
    np.testing.assert_allclose(np.linalg.norm(linked, axis=1), 1.0, rtol=1e-6)
    np.testing.assert_array_equal(linked[2], emb[2])  # named by no answer: unchanged
    expected = _unit(emb[0].astype(np.float64) + 0.4 * stapler)  # the name's unit vector, times the share
    np.testing.assert_allclose(linked[0], expected, rtol=1e-5)
    assert float(linked[0] @ stapler) > float(emb[0] @ stapler)
    for row in (1, 3):  # every class of a shared name is linked
        np.testing.assert_allclose(linked[row], _unit(emb[row].astype(np.float64) + 0.05 * bird), rtol=1e-5)
    # a photo read as "computer mouse" now lands nearer the stapler than before
    probs = np.array([[0.7, 0.0, 0.3, 0.0]])
    assert float(conse_embed(probs, linked, 2)[0] @ stapler) > float(conse_embed(probs, emb, 2)[0] @ stapler)
    with pytest.raises(EncoderError, match=r"'stapler'.*not an ImageNet-1k class"):
        link_class_embeddings(emb, classes, {"stapler": [("stapler", 0.5)]}, {"stapler": stapler})


def test_answers_must_be_distinct_classes_with_shares_at_most_whole() -> None:
    ok = ObjectLookalikes.model_validate({"object": "mug", "classes": [{"imagenet_class": "coffee mug", "share": 0.6},
                                                                      {"imagenet_class": "cup", "share": 0.3}]})
    assert [c.imagenet_class for c in ok.classes] == ["coffee mug", "cup"]
    for classes in ([{"imagenet_class": "cup", "share": 0.6}, {"imagenet_class": "cup", "share": 0.1}],
                    [{"imagenet_class": "cup", "share": 0.8}, {"imagenet_class": "coffee mug", "share": 0.4}],
                    [], [{"imagenet_class": "cup", "share": 0.1}] * 6):
        with pytest.raises(ValidationError):
            ObjectLookalikes.model_validate({"object": "mug", "classes": classes})


def test_the_prompt_lists_every_class_the_classifier_can_answer() -> None:
    call = object_call(LOOKALIKE_PROMPT_ID, "stapler", "a machine that fastens papers together")
    text = call.template.render(**call.variables)[1].content
    assert "a machine that fastens papers together" in text
    assert "; ".join(imagenet_class_names()) in text


def test_lookalike_answers_are_recorded_checked_and_built_into_the_bundle(
    tmp_path: Path, clone_cache: Callable[[Path], Path],
) -> None:
    cache = clone_cache(tmp_path / "cache")
    source = fixture_source(cache)
    objects = read_vocabulary(KB_SMALL / "objects.txt", kind="objects")
    assert set(pending_object_calls(LOOKALIKE_PROMPT_ID, source, objects.names, objects.glosses)) == set(objects.names)
    answers = tmp_path / "lookalikes.jsonl"
    answers.write_text(json.dumps({"object": "knife", "classes": [{"imagenet_class": "letter opener", "share": 0.4},
                                                                  {"imagenet_class": "cleaver", "share": 0.2}]}) + "\n",
                       encoding="utf-8")
    result = record_answers(source, LOOKALIKE_PROMPT_ID, answers, [], objects.names, glosses=objects.glosses)
    assert (result.stored, result.unchanged) == (1, 0)
    assert "knife" not in pending_object_calls(LOOKALIKE_PROMPT_ID, source, objects.names, objects.glosses)
    bad = tmp_path / "bad.jsonl"
    bad.write_text(json.dumps({"object": "spoon", "classes": [{"imagenet_class": "wooden spon", "share": 0.5}]}) + "\n",
                   encoding="utf-8")
    with pytest.raises(CurationError, match=r"bad\.jsonl:1: 'wooden spon' is not an ImageNet-1k class name; "
                                            r"did you mean 'wooden spoon'"):
        record_answers(source, LOOKALIKE_PROMPT_ID, bad, [], objects.names, glosses=objects.glosses)
    built: FixtureKB = _build(cache, tmp_path / "bundle")
    assert load_bundle(built.bundle).lookalikes == {"knife": (("cleaver", 0.2), ("letter opener", 0.4))}


def test_parse_lookalikes_names_the_file_and_the_fault(tmp_path: Path) -> None:
    classes = frozenset(imagenet_class_names())
    good = {"objects": {"mug": {"classes": {"coffee mug": 0.6}}}}
    assert parse_lookalikes(tmp_path, json.dumps(good).encode(), ["mug"], classes) == {"mug": (("coffee mug", 0.6),)}
    bad_cases = [
        ({"objects": {"pear": {"classes": {"coffee mug": 0.6}}}}, "not an object"),
        ({"objects": {"mug": {"classes": {"mug": 0.6}}}}, "not ImageNet-1k classes"),
        ({"objects": {"mug": {"classes": {"coffee mug": 0.8, "cup": 0.4}}}}, "adding up"),
        ({"objects": {"mug": {"classes": {}}}}, "one to five"),
        ({"objects": {"mug": {"shares": {}}}}, "'classes'"),
        ({"nothing": 1}, "does not parse"),
    ]
    for body, message in bad_cases:
        with pytest.raises(LookalikesError, match=message) as exc:
            parse_lookalikes(tmp_path, json.dumps(body).encode(), ["mug"], classes)
        assert "object_lookalikes.json" in str(exc.value)


def test_a_tampered_lookalike_file_is_refused(tmp_path: Path, kb_a: FixtureKB) -> None:
    folder = tmp_path / "kb"
    shutil.copytree(kb_a.bundle, folder)
    (folder / "object_lookalikes.json").write_text('{"objects": {}}\n', encoding="utf-8")
    with pytest.raises(BundleError, match=r"object_lookalikes\.json"):
        load_bundle(folder)


def test_every_sim_name_has_lookalikes_in_the_shipped_bundles() -> None:
    for name in ("craft-e-default", "direct-llm", "conceptnet"):
        assert set(sim_vocabulary()) <= set(load_bundle(KB_DIR / name).lookalikes), name


def test_the_linked_encoder_names_its_table_and_needs_a_covered_vocabulary(kb_a: FixtureKB) -> None:
    encoder = ConSEImageEncoder(preprocess="fit")
    bundle = load_bundle(KB_DIR / "craft-e-default")
    linked = linked_encoder(encoder, bundle, sim_vocabulary())
    assert linked.id.startswith(encoder.id + "+look:") and linked.classifier is encoder.classifier
    assert linked.fused().id == linked.id + "+fused"
    stapler = bundle.embeddings["object"][bundle.object_index["stapler"]]
    for cls, _ in bundle.lookalikes["stapler"]:  # every class the stapler's answer names moved toward it
        row = imagenet_class_names().index(cls)
        assert float(linked.class_embeddings[row] @ stapler) > float(encoder.class_embeddings[row] @ stapler)
    untouched = [i for i, c in enumerate(imagenet_class_names())
                 if all(c not in dict(v) for v in bundle.lookalikes.values())]
    np.testing.assert_array_equal(linked.class_embeddings[untouched], encoder.class_embeddings[untouched])
    with pytest.raises(LookalikesUnavailableError, match=r"no look-alike classes for 'accordion'.*object_lookalike"):
        linked_encoder(encoder, bundle, [*sim_vocabulary(), "accordion"])
    with pytest.raises(LookalikesUnavailableError, match="no look-alike classes"):
        linked_encoder(encoder, load_bundle(kb_a.bundle), ["knife"])
    assert GroundingSettings(lookalikes=True).energy_dict()["lookalikes"] is True
    assert "lookalikes" not in GroundingSettings().energy_dict()  # unset: stored results read as before
