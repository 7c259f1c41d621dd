"""The cavity cue: an open hollow measured from depth, weighed against the KB's "is concave"."""

from __future__ import annotations

import numpy as np
import pytest

from craft_e.paths import KB_DIR
from craft_e.runtime.grounding.cavity_cue import (
    SEEN_IF_CONCAVE,
    SEEN_IF_NOT,
    THRESHOLD_M,
    cavity_log_likelihood,
    cavity_table,
    depth_bound,
    with_cavity_cue,
)
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.runtime.kb.sizes import TypicalSize
from craft_e.runtime.perception.cavity import measure_cavity
from craft_e.runtime.perception.roi import ROI
from craft_e.runtime.sim.pipeline import sim_vocabulary


def _disc(size: int = 120, radius: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """A round footprint centred in a ``size``-pixel frame: (radius of each pixel, mask)."""
    yy, xx = np.mgrid[:size, :size]
    r = np.hypot(yy - size / 2, xx - size / 2)
    return r, r <= radius


def test_a_cup_shows_its_cavity_a_dome_and_a_flat_top_do_not() -> None:
    r, mask = _disc()
    cup = np.where(r > 34, 0.09, 0.01)  # a 6-pixel rim 9 cm high around a floor 1 cm high
    dome = 0.06 * np.sqrt(np.clip(1 - (r / 40) ** 2, 0, 1))  # a ball's top
    flat = np.full(r.shape, 0.05)  # a box's lid
    cavity = measure_cavity(cup, mask)
    assert cavity is not None and cavity == pytest.approx(0.08, abs=1e-9)
    dome_cavity, flat_cavity = measure_cavity(dome, mask), measure_cavity(flat, mask)
    assert dome_cavity is not None and dome_cavity < 0
    assert flat_cavity == pytest.approx(0.0, abs=1e-12)


def test_a_rim_must_enclose_the_core_one_raised_end_is_not_a_hollow() -> None:
    """A bottle lying on its side with its cap end raised: high at one end of its outline only.
    The band's 90th percentile over all its pixels would call it 7 cm deep; the enclosing rim,
    the median over the sectors around it, does not."""
    yy, xx = np.mgrid[:60, :140]
    mask = (np.abs(yy - 30) <= 15) & (np.abs(xx - 70) <= 60)  # 31 x 121 pixels
    bottle = np.where(xx > 115, 0.10, 0.03)  # the body 3 cm high, the last 15 pixels 10 cm
    cavity = measure_cavity(bottle, mask)
    assert cavity is not None and cavity < 0.005
    walled = np.where((np.abs(yy - 30) > 9) | (np.abs(xx - 70) > 54), 0.10, 0.03)  # a tray, walled all round
    tray = measure_cavity(walled, mask)
    assert tray is not None and tray == pytest.approx(0.07, abs=1e-9)


def test_too_small_or_too_thin_regions_are_not_measured() -> None:
    heights = np.full((50, 50), 0.02)
    tiny = np.zeros((50, 50), bool)
    tiny[10:15, 10:15] = True  # 25 pixels
    thin = np.zeros((50, 50), bool)
    thin[5:45, 20:23] = True  # a marker 3 pixels wide: no core survives the erosion
    assert measure_cavity(heights, tiny) is None
    assert measure_cavity(heights, thin) is None


def test_the_crop_gives_what_the_whole_frame_gives() -> None:
    """The measure works on the mask's box; the same region anywhere in a frame reads the same."""
    r, mask = _disc(100, 30)
    cup = np.where(r > 25, 0.08, 0.0)
    frame_h, frame_m = np.zeros((480, 640)), np.zeros((480, 640), bool)
    frame_h[200:300, 300:400], frame_m[200:300, 300:400] = cup, mask
    assert measure_cavity(frame_h, frame_m) == measure_cavity(cup, mask)


def test_the_table_reads_the_kb_and_declines_bundles_without_the_property() -> None:
    names = ["cup", "bowl", "knife", "tennis ball", "spoon"]
    table = cavity_table(names, load_bundle(KB_DIR / "craft-e-default"))
    assert table is not None
    seen = dict(zip(names, table.tolist(), strict=True))
    # "is concave" 1.0 in the KB and 16 x 16 x 7 cm: deep enough, the bound 0.999
    assert seen["bowl"] == pytest.approx(SEEN_IF_CONCAVE, abs=1e-3)
    assert seen["knife"] == pytest.approx(SEEN_IF_NOT, abs=1e-6)  # no edge: not hollow
    assert seen["cup"] > seen["tennis ball"]
    # the spoon is concave (1.0) but 2 cm thick, the threshold: half its instances could show it
    assert seen["spoon"] == pytest.approx(0.5 * SEEN_IF_CONCAVE + 0.5 * SEEN_IF_NOT, abs=1e-6)
    assert cavity_table(names, load_bundle(KB_DIR / "direct-llm")) is None  # no properties at all
    assert cavity_table([*names, "no such object"], load_bundle(KB_DIR / "craft-e-default")) is None


def test_the_depth_bound_is_the_chance_an_instance_is_thicker_than_the_threshold() -> None:
    thick = TypicalSize((0.11, 0.09, 0.08), "medium")
    assert depth_bound(thick) == pytest.approx(1.0, abs=1e-3)
    at = TypicalSize((0.18, 0.04, THRESHOLD_M), "medium")
    assert depth_bound(at) == pytest.approx(0.5)
    thin = TypicalSize((0.2, 0.1, 0.01), "low")  # half the threshold, instances within ~20 %
    assert depth_bound(thin) < 1e-3
    assert depth_bound(TypicalSize((0.2, 0.1, 0.01), "high")) > depth_bound(thin)  # a wider spread
    assert depth_bound(None) == 1.0  # no recorded size: no bound
    assert depth_bound(at, threshold_m=0.01) > 0.9


def test_a_cavity_favours_hollow_names_and_its_absence_weakly_disfavours_them() -> None:
    table = np.array([SEEN_IF_CONCAVE, SEEN_IF_NOT], dtype=np.float32)  # [a cup, a knife]
    ll = cavity_log_likelihood(np.array([0.06, 0.0, np.nan]), table)
    assert ll.shape == (3, 2)
    # 6 cm deep: all but certainly seen; 0 cm: all but certainly not (the soft threshold's tails)
    assert np.exp(ll[0, 0] - ll[0, 1]) == pytest.approx(SEEN_IF_CONCAVE / SEEN_IF_NOT, rel=0.02)
    assert np.exp(ll[1, 0] - ll[1, 1]) == pytest.approx((1 - SEEN_IF_CONCAVE) / (1 - SEEN_IF_NOT), rel=0.05)
    assert ll[2].tolist() == [0.0, 0.0]  # not measured: neutral
    p = np.array([[0.5, 0.5], [0.5, 0.5], [0.5, 0.5]], dtype=np.float32)
    weighed = with_cavity_cue(p, ll)
    assert weighed[0, 0] > 0.9 and 0.25 < weighed[1, 0] < 0.5 and weighed[2].tolist() == [0.5, 0.5]


def test_grounder_applies_the_cavity_cue_where_the_bundle_can_unless_turned_off() -> None:
    bundle = load_bundle(KB_DIR / "craft-e-default")
    vocabulary = list(sim_vocabulary())
    plain = Grounder(bundle, GroundingSettings(vocabulary=vocabulary, cavity_cue=False))
    cued = Grounder(bundle, GroundingSettings(vocabulary=vocabulary))  # the default: on where it can
    assert not plain.cavity_cue_active and cued.cavity_cue_active
    assert Grounder(bundle, GroundingSettings(vocabulary=vocabulary, cavity_cue=True)).cavity_cue_active
    for name in ("direct-llm", "conceptnet"):  # no "is concave" in their graphs: grounded without it
        assert not Grounder(load_bundle(KB_DIR / name), GroundingSettings(vocabulary=vocabulary)).cavity_cue_active
    emb = bundle.embeddings["object"][bundle.object_index["marker"]]
    hollow = ROI((0, 0, 10, 10), [0.5], image_embedding=emb, cavity_m=0.06)
    unmeasured = ROI((20, 0, 10, 10), [0.5], image_embedding=emb)
    g0, g1 = plain.ground("pour", [hollow, unmeasured]), cued.ground("pour", [hollow, unmeasured])
    assert not g0.cavity_cue_used and g1.cavity_cue_used
    p0 = {r.index: {h.name: h.probability for h in r.hypotheses} for r in g0.ranked}
    p1 = {r.index: {h.name: h.probability for h in r.hypotheses} for r in g1.ranked}
    assert p1[1] == pytest.approx(p0[1], rel=1e-5)  # no measurement: unchanged
    cup_rank = [h.name for h in next(r for r in g1.ranked if r.index == 0).hypotheses]
    assert set(cup_rank[:3]) & {"cup", "mug", "bowl", "pitcher"}  # a hollow "marker" reads as a vessel
    assert g1.ranked[0].index == 0  # and affords pouring more than the same image without a hollow
    assert g1.to_dict()["cavity_cue_used"] is True and g1.to_dict()["ranked"][0]["cavity_cm"] == 6.0
    assert "open cavity from depth: 6.0 cm" in g1.render()
    assert "cavity_cue" not in GroundingSettings().energy_dict()  # unset: stored results read as before
    assert plain.settings.energy_dict()["cavity_cue"] is False


def test_the_service_takes_a_measured_cavity() -> None:
    from fastapi.testclient import TestClient

    from craft_e.runtime.serve.app import build_service, create_app

    service = build_service(KB_DIR / "craft-e-default")
    marker = service.bundle.embeddings["object"][service.bundle.object_index["marker"]].tolist()
    objects = ["marker", "cup", "knife"]
    roi = {"box_xywh": [0, 0, 5, 5], "grasp_scores": [0.9], "image_embedding": marker}
    with TestClient(create_app(service)) as client:
        plain = client.post("/ground", json={"verb": "pour", "rois": [roi], "objects": objects}).json()
        hollow = client.post("/ground", json={"verb": "pour", "objects": objects,
                                              "rois": [{**roi, "cavity_m": 0.06}]}).json()
        bad = client.post("/ground", json={"verb": "pour", "objects": objects,
                                           "rois": [{**roi, "cavity_m": 50.0}]})
    assert "cavity_cue_used" not in plain and "cavity_cm" not in plain["ranked"][0]
    assert hollow["cavity_cue_used"] is True and hollow["ranked"][0]["cavity_cm"] == 6.0
    p_plain = {h["object"]: h["p"] for h in plain["ranked"][0]["hypotheses"]}
    p_hollow = {h["object"]: h["p"] for h in hollow["ranked"][0]["hypotheses"]}
    assert p_hollow["cup"] > p_plain["cup"]  # a region with a 6 cm hollow is more likely the cup
    assert bad.status_code == 422 and bad.json()["detail"][0]["loc"][-1] == "cavity_m"
