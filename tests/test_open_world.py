"""Open world (issue 11): unseen objects inferred from similar KB objects, free requests mapped to
properties or abstained on, through the Grounder, ``craft ground`` and ``POST /ground``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import FixtureKB, fixture_source
from fastapi.testclient import TestClient
from runtime_fixtures import RuntimeKBs, runtime_kbs_fixture, shared_image  # noqa: F401
from typer.testing import CliRunner

from craft_e.runtime.grounding.energies import (
    ENERGY_FORMS,
    affordance_energy_matrix,
    energy_from_property_columns,
    property_specificity,
)
from craft_e.runtime.grounding.grounder import ROI, Grounder
from craft_e.runtime.grounding.open_world import (
    OPEN_WORLD_FILE,
    fit_open_world,
    open_world_json,
    parse_request,
)
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.runtime.serve.app import build_service, create_app
from craft_e.schemas.v1.bundle import listed_files_ok

NONSENSE = "qzx vrrk"


@pytest.mark.parametrize("form", ENERGY_FORMS)
def test_property_columns_reproduce_the_kb_energy(form: Any) -> None:
    rng = np.random.default_rng(0)
    w_vp = np.where(rng.random((5, 12)) < 0.4, rng.random((5, 12)), 0.0).astype(np.float32)
    w_po = np.where(rng.random((12, 30)) < 0.3, rng.random((12, 30)), 0.0).astype(np.float32)
    required = rng.random((5, 12)) < 0.3
    expected = affordance_energy_matrix(w_vp, w_po, tau=0.5, form=form, required=required)
    link = (w_po >= 0.5) & (w_po > 0)
    got = energy_from_property_columns(w_vp, np.where(link, w_po, 0.0), link.astype(np.float64),
                                       specificity=property_specificity(w_po, tau=0.5), form=form,
                                       required=required)
    np.testing.assert_allclose(got, expected, atol=1e-6)


def test_fit_is_deterministic_small_and_monotone() -> None:
    rng = np.random.default_rng(1)
    emb = rng.normal(size=(40, 16)).astype(np.float32)
    w_po = np.where(rng.random((10, 40)) < 0.3, rng.random((10, 40)), 0.0)
    a, b = fit_open_world(emb, w_po, tau=0.5), fit_open_world(emb, w_po, tau=0.5)
    assert open_world_json(a) == open_world_json(b) and len(open_world_json(a)) < 10_000
    curve = a["objects"]["confidence"]["quality"]
    assert curve == sorted(curve) and curve[0] == 0.0  # falls to 0 below the evidence
    assert fit_open_world(emb[:1], w_po[:, :1], tau=0.5)["objects"]["k"] >= 1  # one object: no crash


def test_bundle_ships_and_hashes_the_model(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    assert OPEN_WORLD_FILE in kb.manifest.files and kb.open_world is not None
    assert kb.open_world["objects"]["k"] >= 1 and "min_confidence" in kb.open_world["requests"]
    # a bundle built before the file existed still loads; a foreign file list does not
    files = set(kb.manifest.files)
    assert listed_files_ok(files) and listed_files_ok(files - {OPEN_WORLD_FILE})
    assert not listed_files_ok(files - {"graph.json"}) and not listed_files_ok(files | {"x.bin"})


def test_tampered_model_is_refused(runtime_kbs: RuntimeKBs, tmp_path: Path) -> None:
    import shutil

    from craft_e.runtime.kb.bundle import BundleError

    copy = tmp_path / "kb"
    shutil.copytree(runtime_kbs.kb, copy)
    (copy / OPEN_WORLD_FILE).write_text(json.dumps({"objects": {}}))
    with pytest.raises(BundleError, match=OPEN_WORLD_FILE):
        load_bundle(copy)


def _rois(g: Grounder, names: list[str]) -> list[ROI]:
    emb = g._encoder().embed(names)
    return [ROI(box_xywh=(i * 10.0, 0, 10, 10), grasp_scores=[0.9], image_embedding=emb[i], label=n)
            for i, n in enumerate(names)]


def test_unknown_object_is_inferred_from_similar_objects(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    g = Grounder(kb, GroundingSettings(vocabulary=["meat cleaver", "banana", NONSENSE]), object_min_confidence=0.0)
    inf = g.inferred["meat cleaver"]
    assert inf.confident and inf.neighbours[0][0] == "cleaver"
    res = g.ground("cut", _rois(g, ["meat cleaver", "banana"]))
    best = res.chosen
    assert best is not None and best.hypotheses[0].name == "meat cleaver" and best.e_aff < 0
    assert best.inference is inf and best.paths and all("inferred" in p.provenance for p in best.paths)
    text = res.render()
    assert "inferred from similar objects: cleaver" in text and "(conf." in text
    assert res.to_dict()["ranked"][0]["inferred"]["neighbours"][0]["object"] == "cleaver"


def test_unknown_object_without_confidence_is_flagged_not_guessed(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    g = Grounder(kb, GroundingSettings(vocabulary=["banana", NONSENSE]), object_min_confidence=0.99)
    col = g.vocabulary.index(NONSENSE)
    assert not g.inferred[NONSENSE].confident and not g._eaff[:, col].any()  # E_aff = 0: alignment alone
    res = g.ground("cut", _rois(g, [NONSENSE]))
    assert "unknown object: alignment only" in res.render() and "no confident inference" in res.render()


def test_parse_request() -> None:
    assert parse_request("Give me something to open a beer bottle!") == "open a beer bottle"
    assert parse_request("something for digging") == "digging"
    assert parse_request("I need to dig a hole") == "dig a hole"
    assert parse_request("cut") == "cut"


def test_phrase_is_mapped_to_properties_with_paths(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    g = Grounder(kb, GroundingSettings(open_vocab=True), request_min_confidence=0.0)
    assert g.ground("give me something to cut", _rois(g, ["cleaver"])).request is None  # a KB verb
    res = g.ground("chop firewood", _rois(g, ["hatchet", "banana", "violin"]))
    assert res.request is not None and not res.abstained and res.open_vocab_used
    assert res.request.verbs and res.request.properties and res.request.weights.sum() > 0
    best = res.chosen
    assert best is not None and best.paths and best.paths[0].verb == "chop firewood"
    d = res.to_dict()
    assert d["request"]["task"] == "chop firewood" and d["request"]["property_weights"]
    assert "mapped to properties" in res.render()


def test_low_confidence_request_abstains(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    g = Grounder(kb, GroundingSettings(open_vocab=True), request_min_confidence=0.99)
    res = g.ground("decorate", _rois(g, ["hatchet", "banana"]))
    assert res.abstained and res.chosen is None and all(r.e_aff == 0.0 for r in res.ranked)
    assert "I don't know what 'decorate' needs" in res.render()
    assert res.to_dict()["abstained"] is True and res.to_dict()["chosen"] is None


def test_serve_accepts_phrases_and_unknown_objects(runtime_kbs: RuntimeKBs) -> None:
    svc = build_service(runtime_kbs.kb, image_encoder=None, settings=GroundingSettings(open_vocab=True))
    g = svc.grounders[svc.default_form]
    emb = g._encoder().embed(["meat cleaver", "banana"])
    rois = [{"box_xywh": [0, 0, 5, 5], "grasp_scores": [0.9], "image_embedding": emb[0].tolist()},
            {"box_xywh": [5, 0, 5, 5], "grasp_scores": [0.9], "image_embedding": emb[1].tolist()}]
    with TestClient(create_app(svc)) as c:
        r = c.post("/ground", json={"verb": "cut", "rois": rois, "objects": ["meat cleaver", "banana"]})
        assert r.status_code == 200, r.text
        top = r.json()["ranked"][0]
        assert top["hypotheses"][0]["object"] == "meat cleaver" and top["inferred"]["object"] == "meat cleaver"
        r = c.post("/ground", json={"verb": NONSENSE, "rois": rois})
        assert r.status_code == 200, r.text
        d = r.json()
        assert d["abstained"] is True and d["chosen"] is None and d["chosen_grasp"] is None
        assert "I don't know what" in d["request"]["message"]
        r = c.post("/ground", json={"verb": "chop firewood", "rois": rois})
        assert r.status_code == 200 and r.json()["request"]["task"] == "chop firewood"
        r = c.post("/ground", json={"verb": "cut", "rois": rois, "objects": ["banana", "banana"]})
        assert r.status_code == 422


def test_cli_ground_accepts_phrases_and_unknown_objects(runtime_kbs: RuntimeKBs, tmp_path: Path) -> None:
    from craft_e.runtime.cli.main import app

    vocab = tmp_path / "vocab.txt"
    vocab.write_text("meat cleaver\nbanana\nviolin\n")
    out = tmp_path / "g.json"
    result = CliRunner().invoke(app, [
        "ground", "--kb", str(runtime_kbs.kb), "--verb", "something to chop firewood", "--open-vocab",
        "--vocab", str(vocab), "--image", str(shared_image("hatchet")), "--box", "0,0,200,200",
        "--json", str(out), "--threads", "1"])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert data["request"]["task"] == "chop firewood" and "open vocabulary" in result.output
    result = CliRunner().invoke(app, [
        "ground", "--kb", str(runtime_kbs.kb), "--verb", NONSENSE, "--open-vocab",
        "--image", str(shared_image("hatchet")), "--box", "0,0,200,200", "--threads", "1"])
    assert result.exit_code == 0, result.output
    assert "I don't know what" in result.output and "abstained" in result.output


def test_adding_objects_asks_only_for_the_new_ones(kb_a: FixtureKB) -> None:
    """Issue 11 item 3: ``craftc build --objects more.txt`` plans requests for new objects only."""
    from craft_e.compiler.llm_knowledge import plan_object_calls

    props = load_bundle(kb_a.bundle, check_encoder=False).manifest.properties
    source = fixture_source(kb_a.cache)
    covering, calls = plan_object_calls(source, ["knife", "spoon", "bowl", "cup", "ladle"], props, version="v1")
    assert [c.subject for c in calls] == ["ladle"]
    assert all(covering[o] for o in ("knife", "spoon", "bowl", "cup"))


def test_diff_shows_added_objects_and_their_ranking_effects(kb_a: FixtureKB, kb_b2: FixtureKB) -> None:
    from craft_e.compiler.diff import diff_bundles, render_markdown

    a, b = load_bundle(kb_a.bundle, check_encoder=False), load_bundle(kb_b2.bundle, check_encoder=False)
    result = diff_bundles(a, b)
    assert "ladle" in result["objects"]["added"]
    md = render_markdown(result)
    assert "### Added objects: ranking changes they cause" in md
    effects = {e["object"]: e for e in result["added_objects_ranked"]}
    if "ladle" in effects:
        assert effects["ladle"]["verbs"] and "`ladle`" in md
