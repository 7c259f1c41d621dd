"""The size cue: object_size records -> bundle's object_sizes.json -> p(o | r) weighed by the
ROI's extents from depth. Fixture records use provider ``test-fixture`` (never ``curated``)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import KB_SMALL, FixtureKB, _build, fixture_source

from craft_e.compiler.curate import CurationError, record_answers
from craft_e.compiler.object_sizes import pending_size_calls
from craft_e.compiler.vocab import read_vocabulary
from craft_e.paths import KB_DIR
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.grounding.size_cue import size_log_likelihood, size_table, with_size_cue
from craft_e.runtime.kb.bundle import BundleError, load_bundle
from craft_e.runtime.kb.sizes import SizesError, TypicalSize, parse_sizes
from craft_e.runtime.perception.extents import measure_extents
from craft_e.runtime.perception.roi import ROI
from craft_e.runtime.sim.pipeline import sim_vocabulary

SIZES = {
    "apple": TypicalSize((0.08, 0.08, 0.075), "medium"),
    "hammer": TypicalSize((0.33, 0.13, 0.035), "low"),
    "marker": TypicalSize((0.14, 0.018, 0.018), "low"),
}


def _box_points(length: float, width: float, height: float, yaw_deg: float, n: int = 4000) -> np.ndarray:
    """Points on the top and sides of a box standing on a table at z = 0, turned by ``yaw``."""
    rng = np.random.default_rng(0)
    local = rng.uniform([-length / 2, -width / 2, 0.0], [length / 2, width / 2, height], size=(n, 3))
    local[: n // 2, 2] = height  # half the points on the top face, as a top view sees it
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    xy = local[:, :2] @ np.array([[c, s], [-s, c]])
    return np.column_stack([xy + np.array([0.4, 0.1]), local[:, 2]])


def test_extents_are_the_box_edges_longest_first_whatever_the_yaw() -> None:
    for yaw in (0.0, 30.0, 90.0):
        edges = measure_extents(_box_points(0.10, 0.04, 0.06, yaw), table_z=0.0)
        assert edges is not None
        np.testing.assert_allclose(edges, (0.10, 0.06, 0.04), atol=0.004)
    assert measure_extents(_box_points(0.1, 0.04, 0.06, 0.0, n=10), table_z=0.0) is None
    nan_rows = np.full((100, 3), np.nan)
    assert measure_extents(nan_rows, table_z=0.0) is None


def test_size_likelihood_prefers_the_name_whose_size_fits() -> None:
    names = ["apple", "hammer", "marker"]
    table = size_table(names, SIZES)
    assert table is not None
    extents = np.array([[0.085, 0.08, 0.07], [0.30, 0.12, 0.04], [np.nan, np.nan, np.nan]])
    ll = size_log_likelihood(extents, table)
    assert ll.shape == (3, 3)
    assert int(np.argmax(ll[0])) == 0 and int(np.argmax(ll[1])) == 1
    assert (ll[2] == 0).all()  # unmeasured: neutral
    p = np.full((3, 3), 1 / 3, dtype=np.float32)
    q = with_size_cue(p, ll)
    np.testing.assert_allclose(q.sum(axis=1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(q[2], p[2], rtol=1e-6)
    assert q[0, 0] > 0.9 and q[1, 1] > 0.9
    # a name without a size: no table (a partial cue would favour the unmeasured names)
    assert size_table([*names, "accordion"], SIZES) is None


def test_parse_sizes_names_the_file_and_the_fault(tmp_path: Path) -> None:
    good = {"objects": {"apple": {"dimensions_cm": [8, 8, 7.5], "variability": "medium"}}}
    assert parse_sizes(tmp_path, json.dumps(good).encode(), ["apple"])["apple"].dimensions_m == (0.08, 0.08, 0.075)
    bad_cases = [
        ({"objects": {"pear": {"dimensions_cm": [9, 7, 7], "variability": "low"}}}, "not an object"),
        ({"objects": {"apple": {"dimensions_cm": [7, 8, 8], "variability": "low"}}}, "longest first"),
        ({"objects": {"apple": {"dimensions_cm": [8, 8, 7], "variability": "huge"}}}, "variability"),
        ({"objects": {"apple": {"variability": "low"}}}, "dimensions_cm"),
        ({"nothing": 1}, "does not parse"),
    ]
    for body, message in bad_cases:
        with pytest.raises(SizesError, match=message) as exc:
            parse_sizes(tmp_path, json.dumps(body).encode(), ["apple"])
        assert "object_sizes.json" in str(exc.value)


def test_grounder_applies_the_cue_to_measured_rois_only() -> None:
    bundle = load_bundle(KB_DIR / "craft-e-default")
    vocabulary = list(sim_vocabulary())
    plain = Grounder(bundle, GroundingSettings(vocabulary=vocabulary, size_cue=False))
    sized = Grounder(bundle, GroundingSettings(vocabulary=vocabulary, size_cue=True))
    assert Grounder(bundle, GroundingSettings(vocabulary=vocabulary)).size_cue_active  # default: where it can
    assert not plain.size_cue_active
    emb = bundle.embeddings["object"][[bundle.object_index["marker"], bundle.object_index["hammer"]]]
    hammer_sized = (0.33, 0.13, 0.035)
    extents = np.array([hammer_sized, (np.nan,) * 3])
    p0 = plain.energies("cut", emb).p_obj
    p1 = sized.energies("cut", emb, extents=extents).p_obj
    table = size_table(vocabulary, bundle.sizes)
    assert table is not None
    np.testing.assert_allclose(p1, with_size_cue(p0, size_log_likelihood(extents, table)), rtol=1e-5, atol=1e-7)
    # the unmeasured ROI keeps its image-only p (to float32 rounding: renormalised, and the
    # vectorised sums' order differs between CPU instruction sets)
    np.testing.assert_allclose(p1[1], p0[1], rtol=1e-6, atol=0)
    hammer = vocabulary.index("hammer")
    assert p1[0, hammer] > p0[0, hammer]
    # ground() reads the ROI's extents
    rois = [ROI((0, 0, 10, 10), [0.5], image_embedding=emb[0], extents_m=hammer_sized)]
    top = sized.ground("cut", rois).ranked[0].hypotheses[0]
    assert top.name == vocabulary[int(p1[0].argmax())]
    assert top.probability == pytest.approx(float(p1[0].max()), rel=1e-5)
    assert sized.settings.energy_dict()["size_cue"] is True
    assert "size_cue" not in GroundingSettings().energy_dict()  # unset: stored results read as before
    with pytest.raises(ValueError, match="no typical size"):
        Grounder(bundle, GroundingSettings(vocabulary=[*vocabulary, "accordion"], size_cue=True))
    # the default turns itself off for a vocabulary it cannot cover (e.g. ImageNet's classes)
    assert not Grounder(bundle, GroundingSettings(vocabulary=[*vocabulary, "accordion"])).size_cue_active


def test_every_sim_name_has_a_recorded_size_in_the_shipped_bundles() -> None:
    for name in ("craft-e-default", "direct-llm", "conceptnet"):
        sizes = load_bundle(KB_DIR / name).sizes
        assert set(sim_vocabulary()) <= set(sizes), name


def test_size_answers_are_recorded_and_built_into_the_bundle(
    tmp_path: Path, clone_cache: Callable[[Path], Path],
) -> None:
    cache = clone_cache(tmp_path / "cache")
    source = fixture_source(cache)
    objects = read_vocabulary(KB_SMALL / "objects.txt", kind="objects")
    assert set(pending_size_calls(source, objects.names, objects.glosses)) == set(objects.names)
    answers = tmp_path / "sizes.jsonl"
    answers.write_text(json.dumps({"object": "knife", "dimensions_cm": [26, 3, 2], "variability": "medium"})
                       + "\n" + json.dumps({"object": "ladle", "dimensions_cm": [30, 9, 7], "variability": "low"})
                       + "\n", encoding="utf-8")
    result = record_answers(source, "object_size", answers, [], objects.names, glosses=objects.glosses)
    assert (result.stored, result.unchanged) == (1, 0)
    assert "ladle" in result.skipped[0]  # not in the objects file: named, not stored
    again = record_answers(source, "object_size", answers, [], objects.names, glosses=objects.glosses)
    assert (again.stored, len(again.skipped)) == (0, 2)  # knife is no longer pending
    assert "knife" not in pending_size_calls(source, objects.names, objects.glosses)
    bad = tmp_path / "bad.jsonl"
    bad.write_text(json.dumps({"object": "spoon", "dimensions_cm": [2, 18, 4], "variability": "low"}) + "\n",
                   encoding="utf-8")
    with pytest.raises(CurationError, match=r"bad\.jsonl:1: .*longest first"):
        record_answers(source, "object_size", bad, [], objects.names, glosses=objects.glosses)
    built: FixtureKB = _build(cache, tmp_path / "bundle")
    sizes = load_bundle(built.bundle).sizes
    assert sizes == {"knife": TypicalSize((0.26, 0.03, 0.02), "medium")}


def test_a_tampered_size_file_is_refused(tmp_path: Path, kb_a: FixtureKB) -> None:
    import shutil

    folder = tmp_path / "kb"
    shutil.copytree(kb_a.bundle, folder)
    (folder / "object_sizes.json").write_text('{"objects": {}}\n', encoding="utf-8")
    with pytest.raises(BundleError, match=r"object_sizes\.json"):
        load_bundle(folder)


def test_the_service_takes_measured_extents() -> None:
    from fastapi.testclient import TestClient

    from craft_e.runtime.serve.app import build_service, create_app

    service = build_service(KB_DIR / "craft-e-default")
    marker = service.bundle.embeddings["object"][service.bundle.object_index["marker"]].tolist()
    objects = ["marker", "hammer", "apple"]
    roi = {"box_xywh": [0, 0, 5, 5], "grasp_scores": [0.9], "image_embedding": marker}
    with TestClient(create_app(service)) as client:
        plain = client.post("/ground", json={"verb": "hit", "rois": [roi], "objects": objects}).json()
        sized = client.post("/ground", json={"verb": "hit", "objects": objects,
                                             "rois": [{**roi, "extents_m": [0.035, 0.33, 0.13]}]}).json()
        bad = client.post("/ground", json={"verb": "hit", "objects": objects,
                                           "rois": [{**roi, "extents_m": [0.1, -0.2, 0.1]}]})
    assert plain["size_cue_used"] is False and plain["ranked"][0]["extents_cm"] is None
    assert sized["size_cue_used"] is True and sized["ranked"][0]["extents_cm"] == [33.0, 13.0, 3.5]
    p_plain = {h["object"]: h["p"] for h in plain["ranked"][0]["hypotheses"]}
    p_sized = {h["object"]: h["p"] for h in sized["ranked"][0]["hypotheses"]}
    assert p_sized["hammer"] > p_plain["hammer"]  # a 33 cm region is more likely the hammer
    assert bad.status_code == 422 and bad.json()["detail"][0]["loc"][-1] == "extents_m"


def test_cli_size_cue_without_sizes_is_a_clear_error(tmp_path: Path, kb_a: FixtureKB) -> None:
    """``--size-cue`` over a bundle with no typical sizes exits 2 naming the fix; nothing written."""
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    out = tmp_path / "demo"
    result = CliRunner().invoke(app, ["sim", "demo", "--verb", "cut", "--kb", str(kb_a.bundle),
                                      "--size-cue", "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert "no typical size" in result.output and "craftc curate pending --prompt object_size" in result.output
    assert not out.exists()


@pytest.mark.parametrize("n", [30, 31, 101, 2000, 6543])
def test_extents_percentiles_equal_numpy_percentile(n: int) -> None:
    """``extents._percentiles`` and ``measure_extents`` give numpy's values bit for bit (the
    form they replaced: one ``np.percentile`` over the height and both spans)."""
    from craft_e.runtime.perception.extents import (
        EDGE_PERCENTILE,
        TOP_PERCENTILE,
        _percentiles,
        measure_extents,
    )

    rng = np.random.default_rng(n)
    pts = rng.normal(0, 1, (n, 3)) * [0.05, 0.02, 0.01] + [0.4, 0.1, 0.75]
    pts[: n // 7, 2] = 0.75  # ties
    for column in pts.T:
        for percents in ((98.0,), (99.0, 1.0), (50.0, 0.0, 100.0, 37.5)):
            assert _percentiles(column, percents) == [float(v) for v in np.percentile(column, percents)]
    xy = pts[:, :2] - pts[:, :2].mean(axis=0)
    _, axes = np.linalg.eigh(np.cov(xy.T))
    q = np.percentile(np.column_stack([pts[:, 2], xy @ axes]),
                      [TOP_PERCENTILE, 100 - EDGE_PERCENTILE, EDGE_PERCENTILE], axis=0)
    spans = q[1, 1:] - q[2, 1:]
    want = tuple(sorted((float(spans[0]), float(spans[1]), float(q[0, 0]) - 0.7), reverse=True))
    with_nan = np.vstack([pts, np.full((3, 3), np.nan)])
    assert measure_extents(pts, 0.7) == want
    assert measure_extents(with_nan, 0.7) == want
