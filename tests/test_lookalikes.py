"""Look-alike knowledge: object_lookalike records -> bundle's object_lookalikes.json -> p(o | r)
weighed by how well the classifier's ImageNet classes fit the classes each name's photos get. Fixture records use provider
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
    CLASS_TOP_K,
    ConSEImageEncoder,
    encode_with_classes,
    imagenet_class_names,
    top_classes,
)
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.grounding.lookalike_cue import (
    KAPPA,
    LAMBDA,
    LookalikeCueUnavailableError,
    lookalike_log_likelihood,
    lookalike_table,
    with_lookalike_cue,
)
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import BundleError, load_bundle
from craft_e.runtime.kb.lookalikes import LookalikesError, parse_lookalikes
from craft_e.runtime.perception.roi import ROI
from craft_e.runtime.sim.pipeline import sim_vocabulary
from craft_e.schemas.v1.payloads import ObjectLookalikes


def test_the_table_spreads_the_unnamed_rest_and_lambda_evenly() -> None:
    classes = ["computer mouse", "crane", "banana", "crane"]  # two classes share a name, as in ImageNet
    answers = {"stapler": (("computer mouse", 0.4), ("crane", 0.2)), "banana": (("banana", 1.0),)}
    table = lookalike_table(["stapler", "banana"], answers, classes)
    assert table is not None and table.shape == (2, 4)
    np.testing.assert_allclose(table.sum(axis=1), 1.0, rtol=1e-6)  # each row is a distribution
    rest = (1 - 0.6) / 4
    np.testing.assert_allclose(table[0], (1 - LAMBDA) * np.array([0.4, 0.1, 0, 0.1]) + (1 - LAMBDA) * rest
                               + LAMBDA / 4, rtol=1e-6)  # 'crane' split between its two classes
    np.testing.assert_allclose(table[1], (1 - LAMBDA) * np.array([0, 0, 1, 0]) + LAMBDA / 4, rtol=1e-6)
    assert lookalike_table(["stapler", "pear"], answers, classes) is None  # partial coverage: no cue


def test_the_likelihood_prefers_the_name_whose_photos_get_the_classes_seen() -> None:
    classes = ["computer mouse", "crane", "banana", "crane"]
    answers = {"stapler": (("computer mouse", 0.4),), "banana": (("banana", 0.9),)}
    table = lookalike_table(["stapler", "banana"], answers, classes)
    assert table is not None
    ll = lookalike_log_likelihood([((0, 0.7), (2, 0.1)), ((2, 0.8),), None], table)
    assert ll.shape == (3, 2)
    assert ll[0, 0] > ll[0, 1] and ll[1, 1] > ll[1, 0]
    assert (ll[2] == 0).all()  # no classes (another encoder): neutral
    expected = KAPPA * np.log(0.7 * table[0, 0] + 0.1 * table[0, 2])
    assert ll[0, 0] == pytest.approx(expected, rel=1e-5)


def test_top_classes_come_from_the_same_pass_as_the_embeddings() -> None:
    rng = np.random.default_rng(0)
    crops = [rng.integers(0, 255, size=(40 + 7 * i, 50, 3), dtype=np.uint8) for i in range(3)]
    encoder = ConSEImageEncoder(preprocess="fit")
    emb, classes = encode_with_classes(encoder, crops)
    np.testing.assert_array_equal(emb, encoder.embed_images(crops))  # the same bits
    probs = encoder.class_probabilities(crops)
    assert classes == top_classes(probs)
    for row, top in zip(probs, classes, strict=True):
        assert top is not None and len(top) == CLASS_TOP_K
        assert [c for c, _ in top] == list(np.argsort(-row, kind="stable")[:CLASS_TOP_K])
    empty, none = encode_with_classes(encoder, [])
    assert empty.shape == (0, encoder.dim) and none == []


def test_grounder_applies_the_lookalike_cue_to_rois_with_classes(kb_a: FixtureKB) -> None:
    bundle = load_bundle(KB_DIR / "craft-e-default")
    vocabulary = list(sim_vocabulary())
    plain = Grounder(bundle, GroundingSettings(vocabulary=vocabulary, size_cue=False))
    cued = Grounder(bundle, GroundingSettings(vocabulary=vocabulary, size_cue=False, lookalikes=True))
    assert cued.lookalike_cue_active and not plain.lookalike_cue_active  # opt-in
    names = imagenet_class_names()
    stapler_class, _ = bundle.lookalikes["stapler"][0]
    seen = ((names.index(stapler_class), 0.8),)
    emb = bundle.embeddings["object"][[bundle.object_index["lemon"], bundle.object_index["lemon"]]]
    p0 = plain.energies("fasten", emb).p_obj
    p1 = cued.energies("fasten", emb, classes=[seen, None]).p_obj
    table = lookalike_table(vocabulary, bundle.lookalikes, names)
    assert table is not None
    np.testing.assert_allclose(p1, with_lookalike_cue(p0, lookalike_log_likelihood([seen, None], table)),
                               rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(p1[1], p0[1], rtol=1e-6)  # no classes: the image-only p
    assert p1[0, vocabulary.index("stapler")] > p0[0, vocabulary.index("stapler")]
    roi = ROI((0, 0, 10, 10), [0.5], image_embedding=emb[0], classes=seen)
    grounding = cued.ground("fasten", [roi])
    assert grounding.lookalike_cue_used and grounding.to_dict()["lookalike_cue_used"] is True
    assert f"the image classifier saw: {stapler_class!r} 0.80" in grounding.render()
    assert "lookalike_cue_used" not in plain.ground("fasten", [roi]).to_dict()  # stored results read as before
    assert cued.settings.energy_dict()["lookalikes"] is True
    assert "lookalikes" not in GroundingSettings().energy_dict()
    with pytest.raises(LookalikeCueUnavailableError, match=r"--lookalikes: .* no look-alike classes for 1 of"):
        Grounder(bundle, GroundingSettings(vocabulary=[*vocabulary, "accordion"], lookalikes=True))
    with pytest.raises(LookalikeCueUnavailableError, match="craftc curate pending --prompt object_lookalike"):
        Grounder(load_bundle(kb_a.bundle), GroundingSettings(lookalikes=True))


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


def test_cli_lookalikes_without_answers_is_a_clear_error(tmp_path: Path, kb_a: FixtureKB) -> None:
    """``--lookalikes`` over a bundle without look-alike classes exits 2 naming the fix; nothing written."""
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    out = tmp_path / "demo"
    result = CliRunner().invoke(app, ["sim", "demo", "--verb", "cut", "--kb", str(kb_a.bundle),
                                      "--no-size-cue", "--lookalikes", "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert "no look-alike classes" in result.output
    assert "craftc curate pending --prompt object_lookalike" in result.output
    assert not out.exists()


def test_the_service_takes_the_classifiers_classes() -> None:
    from fastapi.testclient import TestClient

    from craft_e.runtime.serve.app import build_service, create_app

    service = build_service(KB_DIR / "craft-e-default")
    bundle = service.bundle
    lemon = bundle.embeddings["object"][bundle.object_index["lemon"]].tolist()
    objects = ["lemon", "stapler", "banana"]
    stapler_class = bundle.lookalikes["stapler"][0][0]
    roi = {"box_xywh": [0, 0, 5, 5], "grasp_scores": [0.9], "image_embedding": lemon,
           "imagenet_classes": {stapler_class: 0.8}}
    with TestClient(create_app(service)) as client:
        plain = client.post("/ground", json={"verb": "fasten", "rois": [roi], "objects": objects}).json()
        cued = client.post("/ground", json={"verb": "fasten", "rois": [roi], "objects": objects,
                                            "options": {"lookalikes": True}}).json()
        no_vocabulary = client.post("/ground", json={"verb": "fasten", "rois": [roi], "options": {"lookalikes": True}})
        bad = client.post("/ground", json={"verb": "fasten", "objects": objects,
                                           "rois": [{**roi, "imagenet_classes": {"stapler": 0.5}}]})
    assert "lookalike_cue_used" not in plain and cued["lookalike_cue_used"] is True
    p_plain = {h["object"]: h["p"] for h in plain["ranked"][0]["hypotheses"]}
    p_cued = {h["object"]: h["p"] for h in cued["ranked"][0]["hypotheses"]}
    assert p_cued["stapler"] > p_plain.get("stapler", 0.0)  # a class the stapler's photos get
    assert bad.status_code == 422 and bad.json()["detail"][0]["loc"][-1] == "imagenet_classes"
    assert no_vocabulary.status_code == 422 and "objects" in no_vocabulary.text


def test_craft_ground_takes_lookalikes_over_a_covered_vocabulary(tmp_path: Path) -> None:
    """``craft ground --lookalikes``: the crops' classes come from the embedding's pass; a vocabulary
    the bundle has no look-alikes for exits 2 naming the fix."""
    from runtime_fixtures import shared_image
    from typer.testing import CliRunner

    from craft_e.paths import VOCAB_DIR
    from craft_e.runtime.cli.main import app

    base = ["ground", "--kb", str(KB_DIR / "craft-e-default"), "--verb", "pour", "--image", str(shared_image("teapot")),
            "--box", "0,0,200,200", "--box", "100,50,250,250", "--threads", "1", "--lookalikes"]
    out = tmp_path / "g.json"
    ok = CliRunner().invoke(app, [*base, "--vocab", str(VOCAB_DIR / "sim_objects.txt"), "--json", str(out)])
    assert ok.exit_code == 0, ok.output
    assert "look-alike cue" in ok.output and "the image classifier saw:" in ok.output
    assert json.loads(out.read_text())["lookalike_cue_used"] is True
    missing = CliRunner().invoke(app, base)  # the KB's 628 objects: most have no look-alike answer
    assert missing.exit_code == 2 and "craftc curate pending --prompt object_lookalike" in missing.output
