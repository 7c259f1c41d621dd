"""The colour cue: object_colour records -> bundle's object_colours.json -> p(o | r) weighed by
the colours of the ROI's pixels. Fixture records use provider ``test-fixture`` (never ``curated``)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import KB_SMALL, FixtureKB, _build, fixture_source

from craft_e.compiler.curate import CurationError, record_answers
from craft_e.compiler.object_colours import pending_colour_calls
from craft_e.compiler.vocab import read_vocabulary
from craft_e.paths import KB_DIR
from craft_e.runtime.grounding.colour_cue import (
    colour_log_likelihood,
    colour_table,
    with_colour_cue,
)
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import BundleError, load_bundle
from craft_e.runtime.kb.colours import COLOUR_TERMS, ColoursError, TypicalColours, parse_colours
from craft_e.runtime.perception.colours import colour_terms, measure_colours
from craft_e.runtime.perception.roi import ROI
from craft_e.runtime.sim.pipeline import sim_vocabulary

COLOURS = {
    "banana": TypicalColours((("brown", 0.07), ("yellow", 0.88)), "low"),
    "strawberry": TypicalColours((("green", 0.1), ("red", 0.85)), "low"),
    "mug": TypicalColours((("white", 0.9),), "high"),
}


def _shares(**terms: float) -> list[float]:
    return [terms.get(t, 0.0) for t in COLOUR_TERMS]


def test_pixels_are_named_by_the_basic_colour_terms() -> None:
    named = {
        (230, 30, 30): "red", (255, 140, 0): "orange", (250, 220, 30): "yellow", (20, 160, 40): "green",
        (30, 60, 200): "blue", (120, 40, 160): "purple", (255, 192, 203): "pink", (120, 70, 30): "brown",
        (200, 170, 130): "brown", (10, 10, 10): "black", (128, 128, 128): "grey", (245, 245, 245): "white",
    }
    pixels = np.array(list(named), dtype=np.uint8)
    assert [COLOUR_TERMS[i] for i in colour_terms(pixels)] == list(named.values())
    shares = measure_colours(np.array([[250, 220, 30]] * 90 + [[120, 70, 30]] * 10, dtype=np.uint8))
    assert shares is not None and len(shares) == len(COLOUR_TERMS)
    assert shares[COLOUR_TERMS.index("yellow")] == pytest.approx(0.9)
    assert shares[COLOUR_TERMS.index("brown")] == pytest.approx(0.1)
    assert measure_colours(np.zeros((5, 3), dtype=np.uint8)) is None  # too few pixels: not measured


def test_colour_likelihood_prefers_the_name_whose_colours_fit() -> None:
    names = ["banana", "strawberry", "mug"]
    table = colour_table(names, COLOURS)
    assert table is not None
    np.testing.assert_allclose(np.exp(table).sum(axis=1), 1.0, rtol=1e-5)  # q(o) is a distribution
    shares = np.array([_shares(yellow=0.9, brown=0.1), _shares(red=0.8, green=0.2), [np.nan] * len(COLOUR_TERMS)])
    ll = colour_log_likelihood(shares, table)
    assert ll.shape == (3, 3)
    assert int(np.argmax(ll[0])) == 0 and int(np.argmax(ll[1])) == 1
    assert (ll[2] == 0).all()  # unmeasured: neutral
    # a name "made in any colour" is in between: it cannot win every ROI
    assert ll[0, 1] < ll[0, 2] < ll[0, 0]
    p = np.full((3, 3), 1 / 3, dtype=np.float32)
    q = with_colour_cue(p, ll)
    np.testing.assert_allclose(q.sum(axis=1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(q[2], p[2], rtol=1e-6)
    assert q[0, 0] > q[0, 2] > q[0, 1]
    assert colour_table([*names, "accordion"], COLOURS) is None  # partial coverage: no cue


def test_parse_colours_names_the_file_and_the_fault(tmp_path: Path) -> None:
    good = {"objects": {"banana": {"colours": {"yellow": 0.9}, "variability": "low"}}}
    assert parse_colours(tmp_path, json.dumps(good).encode(), ["banana"])["banana"].shares == (("yellow", 0.9),)
    bad_cases = [
        ({"objects": {"pear": {"colours": {"green": 0.9}, "variability": "low"}}}, "not an object"),
        ({"objects": {"banana": {"colours": {"chartreuse": 0.9}, "variability": "low"}}}, "chartreuse"),
        ({"objects": {"banana": {"colours": {"yellow": 0.9, "brown": 0.3}, "variability": "low"}}}, "adding up"),
        ({"objects": {"banana": {"colours": {"yellow": 0.9}, "variability": "huge"}}}, "variability"),
        ({"objects": {"banana": {"variability": "low"}}}, "'colours'"),
        ({"nothing": 1}, "does not parse"),
    ]
    for body, message in bad_cases:
        with pytest.raises(ColoursError, match=message) as exc:
            parse_colours(tmp_path, json.dumps(body).encode(), ["banana"])
        assert "object_colours.json" in str(exc.value)


def test_grounder_applies_the_colour_cue_to_measured_rois_only() -> None:
    bundle = load_bundle(KB_DIR / "craft-e-default")
    vocabulary = list(sim_vocabulary())
    plain = Grounder(bundle, GroundingSettings(vocabulary=vocabulary, colour_cue=False, size_cue=False))
    coloured = Grounder(bundle, GroundingSettings(vocabulary=vocabulary, colour_cue=True, size_cue=False))
    assert not Grounder(bundle, GroundingSettings(vocabulary=vocabulary)).colour_cue_active  # opt-in
    assert not plain.colour_cue_active
    emb = bundle.embeddings["object"][[bundle.object_index["lemon"], bundle.object_index["lemon"]]]
    shares = np.array([_shares(yellow=0.95, brown=0.05), [np.nan] * len(COLOUR_TERMS)])
    p0 = plain.energies("eat", emb).p_obj
    p1 = coloured.energies("eat", emb, colours=shares).p_obj
    table = colour_table(vocabulary, bundle.colours)
    assert table is not None
    np.testing.assert_allclose(p1, with_colour_cue(p0, colour_log_likelihood(shares, table)), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(p1[1], p0[1], rtol=1e-6)  # the unmeasured ROI keeps its image-only p
    banana = vocabulary.index("banana")
    assert p1[0, banana] > p0[0, banana]  # yellow pixels: the yellow names gain
    roi = ROI((0, 0, 10, 10), [0.5], image_embedding=emb[0], colours=tuple(shares[0]))
    grounding = coloured.ground("eat", [roi])
    assert grounding.colour_cue_used and grounding.to_dict()["ranked"][0]["colours"] == {"yellow": 0.95, "brown": 0.05}
    assert "colours seen: yellow 95 %, brown 5 %" in grounding.render()
    assert coloured.settings.energy_dict()["colour_cue"] is True
    assert "colour_cue" not in GroundingSettings().energy_dict()  # unset: stored results read as before
    with pytest.raises(ValueError, match="no typical colours"):
        Grounder(bundle, GroundingSettings(vocabulary=[*vocabulary, "accordion"], colour_cue=True))


def test_every_sim_name_has_recorded_colours_in_the_shipped_bundles() -> None:
    for name in ("craft-e-default", "direct-llm", "conceptnet"):
        colours = load_bundle(KB_DIR / name).colours
        assert set(sim_vocabulary()) <= set(colours), name


def test_colour_answers_are_recorded_and_built_into_the_bundle(
    tmp_path: Path, clone_cache: Callable[[Path], Path],
) -> None:
    cache = clone_cache(tmp_path / "cache")
    source = fixture_source(cache)
    objects = read_vocabulary(KB_SMALL / "objects.txt", kind="objects")
    assert set(pending_colour_calls(source, objects.names, objects.glosses)) == set(objects.names)
    answers = tmp_path / "colours.jsonl"
    answers.write_text(
        json.dumps({"object": "knife", "colours": [{"colour": "grey", "share": 0.6}, {"colour": "black", "share": 0.4}],
                    "variability": "medium"}) + "\n"
        + json.dumps({"object": "ladle", "colours": [{"colour": "grey", "share": 1.0}], "variability": "low"}) + "\n",
        encoding="utf-8")
    result = record_answers(source, "object_colour", answers, [], objects.names, glosses=objects.glosses)
    assert (result.stored, result.unchanged) == (1, 0)
    assert "ladle" in result.skipped[0]  # not in the objects file: named, not stored
    assert "knife" not in pending_colour_calls(source, objects.names, objects.glosses)
    bad = tmp_path / "bad.jsonl"
    bad.write_text(json.dumps({"object": "spoon", "colours": [{"colour": "grey", "share": 0.8},
                                                              {"colour": "white", "share": 0.5}],
                               "variability": "low"}) + "\n", encoding="utf-8")
    with pytest.raises(CurationError, match=r"bad\.jsonl:1: .*add up to"):
        record_answers(source, "object_colour", bad, [], objects.names, glosses=objects.glosses)
    built: FixtureKB = _build(cache, tmp_path / "bundle")
    assert load_bundle(built.bundle).colours == {"knife": TypicalColours((("black", 0.4), ("grey", 0.6)), "medium")}


def test_a_tampered_colour_file_is_refused(tmp_path: Path, kb_a: FixtureKB) -> None:
    import shutil

    folder = tmp_path / "kb"
    shutil.copytree(kb_a.bundle, folder)
    (folder / "object_colours.json").write_text('{"objects": {}}\n', encoding="utf-8")
    with pytest.raises(BundleError, match=r"object_colours\.json"):
        load_bundle(folder)


def test_the_service_takes_measured_colours() -> None:
    from fastapi.testclient import TestClient

    from craft_e.runtime.serve.app import build_service, create_app

    service = build_service(KB_DIR / "craft-e-default")
    lemon = service.bundle.embeddings["object"][service.bundle.object_index["lemon"]].tolist()
    objects = ["lemon", "banana", "strawberry"]
    roi = {"box_xywh": [0, 0, 5, 5], "grasp_scores": [0.9], "image_embedding": lemon}
    with TestClient(create_app(service)) as client:
        plain = client.post("/ground", json={"verb": "eat", "rois": [roi], "objects": objects}).json()
        red = client.post("/ground", json={"verb": "eat", "objects": objects, "options": {"colour_cue": True},
                                           "rois": [{**roi, "colours": {"red": 0.9, "green": 0.1}}]}).json()
        off = client.post("/ground", json={"verb": "eat", "objects": objects,
                                           "rois": [{**roi, "colours": {"red": 0.9, "green": 0.1}}]}).json()
        no_vocabulary = client.post("/ground", json={"verb": "eat", "options": {"colour_cue": True}, "rois": [roi]})
        bad = client.post("/ground", json={"verb": "eat", "objects": objects,
                                           "rois": [{**roi, "colours": {"chartreuse": 1.0}}]})
    assert plain["colour_cue_used"] is False and plain["ranked"][0]["colours"] is None
    assert red["colour_cue_used"] is True and red["ranked"][0]["colours"] == {"red": 0.9, "green": 0.1}
    p_plain = {h["object"]: h["p"] for h in plain["ranked"][0]["hypotheses"]}
    p_red = {h["object"]: h["p"] for h in red["ranked"][0]["hypotheses"]}
    assert p_red.get("strawberry", 0.0) > p_plain.get("strawberry", 0.0)  # red pixels: the strawberry gains
    assert bad.status_code == 422 and bad.json()["detail"][0]["loc"][-1] == "colours"
    assert off["colour_cue_used"] is False  # opt-in: colours sent, cue not asked for
    assert no_vocabulary.status_code == 422 and "objects" in no_vocabulary.text


def test_cli_colour_cue_without_colours_is_a_clear_error(tmp_path: Path, kb_a: FixtureKB) -> None:
    """``--colour-cue`` over a bundle with no typical colours exits 2 naming the fix; nothing written."""
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    out = tmp_path / "demo"
    result = CliRunner().invoke(app, ["sim", "demo", "--verb", "cut", "--kb", str(kb_a.bundle),
                                      "--no-size-cue", "--colour-cue", "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert "no typical colours" in result.output and "craftc curate pending --prompt object_colour" in result.output
    assert not out.exists()
