"""``Grounder.ground``: energies per ROI, exclusions, modes, unknown verbs, no network."""

from __future__ import annotations

import math
import socket
from typing import Any

import numpy as np
import pytest
from runtime_fixtures import RuntimeKBs, runtime_kbs_fixture, shared_image  # noqa: F401

from craft_e.runtime.grounding.grounder import ROI, Grounder, UnknownVerbError
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import BundleError, load_bundle


def obj_emb(kbs: RuntimeKBs, name: str) -> np.ndarray[Any, np.dtype[np.float32]]:
    """The bundle's text embedding of an object: an ROI that "looks exactly like" it."""
    kb = load_bundle(kbs.kb)
    out: np.ndarray[Any, np.dtype[np.float32]] = kb.embeddings["object"][kb.object_index[name]]
    return out


def test_energies_of_one_roi_by_hand(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    # the paper's plain softmax (the hubness correction's by-hand check: tests/test_hubness.py)
    g = Grounder(kb, GroundingSettings(temperature=0.07, hubness=False))
    e = obj_emb(runtime_kbs, "hatchet")
    res = g.ground("cut", [ROI((0, 0, 10, 10), [0.2, 0.8], image_embedding=e)])
    r = res.ranked[0]
    objs = kb.embeddings["object"] / np.linalg.norm(kb.embeddings["object"], axis=1, keepdims=True)
    cos = objs @ (e / np.linalg.norm(e))
    p = np.exp(cos / 0.07) / np.exp(cos / 0.07).sum()
    row = kb.energy[kb.verb_index["cut"]]
    # the default aff_norm "verb-best": the verb's affordant values divided by its best object's
    e_aff = float(p @ np.where(row < 0, row / -row.min(), row))
    q = kb.embeddings["verb_query"][kb.verb_index["cut"]]
    e_align = math.tanh(-float(q @ e / np.linalg.norm(q) / np.linalg.norm(e)))
    assert r.e_grasp == pytest.approx(-math.log(0.8), abs=1e-6)
    assert r.e_aff == pytest.approx(e_aff, abs=1e-5)
    assert r.e_align == pytest.approx(e_align, abs=1e-5)
    # the default weights (alpha 1, beta 8, gamma 1: grounding/settings.py)
    assert r.total == pytest.approx(1.0 * r.e_grasp + 8.0 * r.e_aff + 1.0 * r.e_align, abs=1e-5)
    assert r.grasp_index == 1 and r.hypotheses[0].name == "hatchet"
    assert {p.prop for p in r.paths} >= {"sharp edge", "has a blade"}
    assert all(p.provenance for p in r.paths)


def test_weights_scale_terms(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    rois = [ROI((0, 0, 1, 1), [0.5], image_embedding=obj_emb(runtime_kbs, "cup"))]
    base = Grounder(kb).ground("pour", rois).ranked[0]
    w = Grounder(kb, GroundingSettings(alpha=2, beta=0.5, gamma=0)).ground("pour", rois).ranked[0]
    assert w.total == pytest.approx(2 * base.e_grasp + 0.5 * base.e_aff, abs=1e-5)


def test_ranking_grasp_exclusion_and_chosen_grasp(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    g = Grounder(kb)
    rois = [
        ROI((0, 0, 5, 5), [0.9], image_embedding=obj_emb(runtime_kbs, "banana"), label="banana"),
        ROI((5, 0, 5, 5), [], image_embedding=obj_emb(runtime_kbs, "cleaver"), label="cleaver-no-grasp"),
        ROI((0, 5, 5, 5), [0.3, 0.9, 0.6], grasps=["g0", "g1", "g2"],
            image_embedding=obj_emb(runtime_kbs, "hatchet"), label="hatchet"),
        ROI((5, 5, 5, 5), [0.9], image_embedding=None, label="no-embedding"),
    ]
    res = g.ground("cut", rois)
    assert [r.roi.label for r in res.ranked] == ["hatchet", "banana"]
    assert res.chosen is not None and res.chosen.grasp == "g1" and res.chosen.grasp_index == 1
    reasons = {e.roi.label: e.reason for e in res.excluded}
    assert set(reasons) == {"cleaver-no-grasp", "no-embedding"}
    assert "no grasp" in reasons["cleaver-no-grasp"]
    text = res.render()
    assert "excluded: no grasp" in text and "why 'hatchet' affords 'cut'" in text
    data = res.to_dict()
    assert data["chosen"] == 2 and len(data["excluded"]) == 2
    # a low grasp score alone can flip the choice
    rois[2] = ROI((0, 5, 5, 5), [1e-4], image_embedding=obj_emb(runtime_kbs, "hatchet"), label="hatchet")
    assert g.ground("cut", rois).ranked[0].roi.label == "banana"
    assert g.ground("cut", [rois[1]]).chosen is None


def test_expected_vs_argmax(runtime_kbs: RuntimeKBs) -> None:
    """An ROI halfway between a cup and a banana: expected mixes both rows, argmax takes one."""
    kb = load_bundle(runtime_kbs.kb)
    mix = obj_emb(runtime_kbs, "cup") + obj_emb(runtime_kbs, "banana")
    roi = [ROI((0, 0, 1, 1), [1.0], image_embedding=mix)]
    exp = Grounder(kb, GroundingSettings(temperature=0.5, aff_mode="expected")).ground("eat", roi).ranked[0]
    arg = Grounder(kb, GroundingSettings(temperature=0.5, aff_mode="argmax")).ground("eat", roi).ranked[0]
    row = kb.energy[kb.verb_index["eat"]]
    assert arg.e_aff == pytest.approx(float(row[kb.object_index[arg.hypotheses[0].name]]), abs=1e-6)
    assert exp.e_aff != pytest.approx(arg.e_aff, abs=1e-3)
    assert min(row) <= exp.e_aff <= max(row)
    assert exp.e_align == pytest.approx(arg.e_align)
    with pytest.raises(ValueError, match="aff_mode"):
        Grounder(kb, GroundingSettings(aff_mode="mean"))


def test_forbidden_pair_is_flagged(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    res = Grounder(kb, GroundingSettings(aff_mode="argmax")).ground("cut", [ROI((0, 0, 1, 1), [1.0], image_embedding=obj_emb(runtime_kbs, "umbrella"))])
    assert res.ranked[0].forbidden and res.ranked[0].e_aff == 1.0
    assert "[forbidden]" in res.render()


def test_unknown_verb_lists_close_matches(runtime_kbs: RuntimeKBs) -> None:
    g = Grounder(load_bundle(runtime_kbs.kb))
    roi = [ROI((0, 0, 1, 1), [1.0], image_embedding=obj_emb(runtime_kbs, "cup"))]
    with pytest.raises(UnknownVerbError) as info:
        g.ground("pourr", roi)
    assert info.value.close_matches[0] == "pour" and "open_vocab" in str(info.value)
    assert g.ground("  Pour ", roi).verb == "pour"  # normalized like the compiler's names


def test_open_vocab_fallback_is_flagged(runtime_kbs: RuntimeKBs) -> None:
    g = Grounder(load_bundle(runtime_kbs.kb), GroundingSettings(open_vocab=True))
    rois = [ROI((0, 0, 1, 1), [1.0], image_embedding=obj_emb(runtime_kbs, o), label=o) for o in ("banana", "teapot")]
    res = g.ground("drink from", rois)
    assert res.open_vocab_used and res.nearest_verbs
    assert abs(sum(w for _, w in res.nearest_verbs)) <= 1.0 + 1e-6
    assert {v for v, _ in res.nearest_verbs} <= set(runtime_kbs.verbs)
    assert "open vocabulary" in res.render() and res.to_dict()["open_vocab_used"] is True
    assert not g.ground("pour", rois).open_vocab_used


def test_non_finite_or_mixed_width_roi_inputs_name_the_roi(runtime_kbs: RuntimeKBs) -> None:
    """NaN embeddings or grasp scores ranked the ROI with a NaN total, silently; a vector of
    another width beside a right one failed inside numpy's stack, naming neither ROI nor field."""
    g = Grounder(load_bundle(runtime_kbs.kb))
    good = ROI((0, 0, 1, 1), [0.9], image_embedding=obj_emb(runtime_kbs, "cleaver"))
    nan = np.full(good.image_embedding.shape, np.nan, np.float32)  # type: ignore[union-attr]
    cases = [(ROI((0, 0, 1, 1), [0.9], image_embedding=nan), "ROI 1: image_embedding holds NaN or infinite"),
             (ROI((0, 0, 1, 1), [0.9], image_embedding=nan * 0 + np.inf), "ROI 1: image_embedding holds NaN"),
             (ROI((0, 0, 1, 1), [float("nan"), 0.5], image_embedding=obj_emb(runtime_kbs, "cup")),
              r"ROI 1: grasp_scores \[nan, 0.5\] hold NaN or infinite values"),
             (ROI((0, 0, 1, 1), [0.9], image_embedding=np.ones(10, np.float32)),
              "ROI 1: image_embedding has 10 values, the bundle's text space")]
    for bad, says in cases:
        with pytest.raises(ValueError, match=says):
            g.ground("cut", [good, bad])
    with pytest.raises(ValueError, match=r"image embeddings hold NaN or infinite values \(row 0\)"):
        g.image_hypotheses(nan[None, :])
    assert np.isfinite(g.ground("cut", [good]).ranked[0].total)


def test_vocabulary_subset_and_unknown_objects(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    g = Grounder(kb, GroundingSettings(vocabulary=["cup", "Bananas", "kettle"]))
    assert g.vocabulary == ["cup", "banana", "kettle"] and g.objects_without_knowledge == ["kettle"]
    res = g.ground("eat", [ROI((0, 0, 1, 1), [1.0], image_embedding=obj_emb(runtime_kbs, "banana"))])
    assert {h.name for h in res.ranked[0].hypotheses} <= {"cup", "banana", "kettle"}
    with pytest.raises(ValueError, match="more than once; keep one entry for each object"):
        Grounder(kb, GroundingSettings(vocabulary=["cup", "cups"]))


def test_embedding_dimension_mismatch_is_an_error(runtime_kbs: RuntimeKBs) -> None:
    g = Grounder(load_bundle(runtime_kbs.kb))
    with pytest.raises(ValueError, match="text space"):
        g.ground("cut", [ROI((0, 0, 1, 1), [1.0], image_embedding=np.ones(512, np.float32))])


def test_bundle_with_other_text_encoder_is_refused(runtime_kbs: RuntimeKBs) -> None:
    with pytest.raises(BundleError, match=r"manifest\.json.*clip-vit-b32"):
        load_bundle(runtime_kbs.other_encoder)
    assert load_bundle(runtime_kbs.other_encoder, check_encoder=False).manifest.text_encoder.id == "clip-vit-b32"


def test_full_grounding_run_opens_no_socket(runtime_kbs: RuntimeKBs, monkeypatch: pytest.MonkeyPatch) -> None:
    """Load bundle, encoders (fresh, from disk), embed crops, ground with the open-vocab fallback."""
    from craft_e.runtime.encoders.conse import ConSEImageEncoder
    from craft_e.runtime.encoders.image import crop_box, load_image
    from craft_e.runtime.encoders.text import MiniLMTextEncoder

    def no_network(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the runtime tried to open a network connection")

    monkeypatch.setattr(socket, "socket", no_network)
    monkeypatch.setattr(socket, "create_connection", no_network)
    monkeypatch.setattr(socket, "getaddrinfo", no_network)
    kb = load_bundle(runtime_kbs.kb)
    enc = ConSEImageEncoder(threads=1)
    img = load_image(str(shared_image("hatchet")))
    crops = [crop_box(img, (0, 0, img.shape[1] // 2, img.shape[0])), crop_box(img, (0, 0, img.shape[1], img.shape[0]))]
    emb = enc.embed_images(crops)
    g = Grounder(kb, GroundingSettings(open_vocab=True), text_encoder=MiniLMTextEncoder())
    res = g.ground("chop", [ROI((0, 0, 1, 1), [0.9], image_embedding=e) for e in emb])
    assert res.open_vocab_used and len(res.ranked) == 2
