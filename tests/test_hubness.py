"""The hubness correction of p(o | r) (``grounding/hubness.py``): CSLS's name term, and its use."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from craft_e.paths import KB_DIR
from craft_e.runtime.encoders.conse import load_class_embeddings
from craft_e.runtime.grounding.energies import object_hypotheses
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.grounding.hubness import (
    HUBNESS_K,
    HubnessUnavailableError,
    name_hubness,
    reference_for,
    with_hubness,
)
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import load_bundle


def test_hubness_is_the_mean_of_the_k_highest_cosines() -> None:
    rng = np.random.default_rng(0)
    names = rng.normal(size=(5, 8)).astype(np.float32)
    reference = rng.normal(size=(40, 8)).astype(np.float32)
    hub = name_hubness(names, reference, k=3)
    a = names / np.linalg.norm(names, axis=1, keepdims=True)
    b = reference / np.linalg.norm(reference, axis=1, keepdims=True)
    expected = np.sort(a @ b.T, axis=1)[:, -3:].mean(axis=1)
    np.testing.assert_allclose(hub, expected, rtol=1e-5, atol=1e-6)
    # k beyond the labels: all of them
    np.testing.assert_allclose(name_hubness(names, reference[:2], k=10), (a @ b[:2].T).mean(axis=1), atol=1e-6)


def test_a_name_near_many_labels_loses_crops_it_only_half_fits() -> None:
    """Two names with the same cosine to a crop: the one with more labels nearby (the hub) now
    gets less probability, by exp(weight * hub gap / T)."""
    hub = np.array([0.7, 0.3], dtype=np.float32)  # name 0 is the hub
    cosine = np.array([[0.5, 0.5]], dtype=np.float32)
    p = object_hypotheses(with_hubness(cosine, hub), 0.1)
    assert p[0, 1] > p[0, 0]
    np.testing.assert_allclose(p[0, 1] / p[0, 0], np.exp(0.5 * 0.4 / 0.1), rtol=1e-4)


def test_bad_shapes_and_k_are_errors() -> None:
    with pytest.raises(ValueError, match="one space"):
        name_hubness(np.ones((2, 3), np.float32), np.ones((4, 5), np.float32))
    with pytest.raises(ValueError, match="k must be"):
        name_hubness(np.ones((2, 3), np.float32), np.ones((4, 3), np.float32), k=0)


def test_the_reference_is_conse_labels_for_its_text_space_only() -> None:
    bundle = load_bundle(KB_DIR / "craft-e-default", check_encoder=False)
    enc = bundle.manifest.text_encoder
    reference = reference_for(enc.id, enc.weights_sha256, 0.5)
    assert reference is not None and reference.shape == (1000, enc.dim)
    assert reference_for("clip-vit-b32", enc.weights_sha256, 0.5) is None
    assert reference_for(enc.id, "0" * 64, 0.5) is None


def test_the_grounder_applies_it_by_default_and_on_request_only() -> None:
    bundle = load_bundle(KB_DIR / "craft-e-default", check_encoder=False)
    vocab = ["knife", "tennis ball", "correction fluid", "cup"]
    on = Grounder(bundle, GroundingSettings(vocabulary=vocab))
    off = Grounder(bundle, GroundingSettings(vocabulary=vocab, hubness=False))
    assert on.hubness_active and not off.hubness_active
    classes = load_class_embeddings()
    crop = classes[:3].mean(axis=0, keepdims=True)  # a crop the classifier spreads over three classes
    verb = on.verbs[0]
    cosine = crop / np.linalg.norm(crop) @ off._obj_emb_t
    np.testing.assert_allclose(off.energies(verb, crop).p_obj, object_hypotheses(cosine, 0.1), rtol=1e-5)
    hub = name_hubness(np.ascontiguousarray(off._obj_emb_t.T), classes, HUBNESS_K)
    np.testing.assert_allclose(on.energies(verb, crop).p_obj, object_hypotheses(with_hubness(cosine, hub), 0.1),
                               rtol=1e-5)
    assert GroundingSettings(hubness=False).energy_dict()["hubness"] is False
    assert "hubness" not in GroundingSettings().energy_dict()


def test_image_hypotheses_are_the_energies_p_obj_before_any_cue() -> None:
    """``image_hypotheses`` is what ``energies`` reads from the embeddings alone (names in their
    sense, less their hubness): recognition scores rank it, so it must not drift from grounding."""
    bundle = load_bundle(KB_DIR / "craft-e-default", check_encoder=False)
    vocab = ["knife", "tennis ball", "correction fluid", "cup"]
    classes = load_class_embeddings()
    crops = np.stack([classes[:3].mean(axis=0), classes[400:410].mean(axis=0)])  # [2, d]
    for settings in (GroundingSettings(vocabulary=vocab), GroundingSettings(vocabulary=vocab, hubness=False)):
        grounder = Grounder(bundle, settings)
        p = grounder.image_hypotheses(crops)
        assert p.shape == (2, 4)
        np.testing.assert_array_equal(p, grounder.energies(grounder.verbs[0], crops).p_obj)
    with pytest.raises(ValueError, match="image embeddings must be"):
        grounder.image_hypotheses(np.ones((2, 7), np.float32))


def test_requiring_it_in_another_text_space_names_the_problem(monkeypatch: pytest.MonkeyPatch) -> None:
    bundle = load_bundle(KB_DIR / "craft-e-default", check_encoder=False)
    monkeypatch.setattr("craft_e.runtime.grounding.grounder.reference_for", lambda *_: None)
    assert not Grounder(bundle).hubness_active  # default: grounds without it
    with pytest.raises(HubnessUnavailableError, match="--hubness: the bundle craft-e-default"):
        Grounder(bundle, GroundingSettings(hubness=True))


def test_a_top_name_without_a_path_is_explained_by_the_next_hypothesis_that_has_one() -> None:
    """E_aff is the expectation over hypotheses: when the most likely name has no verb -> property
    path (a marker for *cut*), the explanation shows the paths of the next one that has (the knife)."""
    from craft_e.runtime.perception.roi import ROI

    bundle = load_bundle(KB_DIR / "craft-e-default", check_encoder=False)
    g = Grounder(bundle, GroundingSettings(vocabulary=["marker", "knife", "cup"], hubness=False))
    assert not g.paths("cut", "marker") and g.paths("cut", "knife")
    emb = bundle.embeddings["object"]
    mix = 0.6 * emb[bundle.object_index["marker"]] + 0.4 * emb[bundle.object_index["knife"]]
    result = g.ground("cut", [ROI((0, 0, 10, 10), [0.9], image_embedding=mix)])
    best = result.ranked[0]
    assert [h.name for h in best.hypotheses[:2]] == ["marker", "knife"]
    assert best.paths and {p.obj for p in best.paths} == {"knife"}
    assert "why 'knife' (hypothesis 2, p " in result.render() and "no path for 'marker')" in result.render()
    only = g.ground("cut", [ROI((0, 0, 10, 10), [0.9], image_embedding=emb[bundle.object_index["knife"]])])
    assert "why 'knife' affords 'cut':" in only.render()


def test_an_unwritable_encoder_cache_costs_a_recomputation_not_the_answer(tmp_path: Path) -> None:
    """Every grounder of a MiniLM bundle reads the class-name embeddings (its hubness reference);
    where the cache folder cannot be written (here: a file stands where the folder should be) they
    are computed and returned, and nothing is left behind."""

    class Fake:
        def embed(self, texts: list[str]) -> np.ndarray:
            return np.arange(len(texts) * 4, dtype=np.float32).reshape(len(texts), 4)

    blocked = tmp_path / "cache"
    blocked.write_text("not a folder", encoding="utf-8")
    emb = load_class_embeddings(blocked / "encoders", text_encoder=Fake(), sense_weight=0.0)  # the names as given
    assert emb.shape == (1000, 4) and emb[1, 0] == 4.0
    assert blocked.read_text(encoding="utf-8") == "not a folder" and sorted(tmp_path.iterdir()) == [blocked]
    sensed = load_class_embeddings(blocked / "encoders", text_encoder=Fake(), sense_weight=0.5)  # + the glosses
    assert sensed.shape == (1000, 4) and sorted(tmp_path.iterdir()) == [blocked]
