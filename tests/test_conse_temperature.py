"""ConSE's weights at a softmax temperature (``encoders/conse.py``, ``conse_temperature``).

What must hold: temperature 1 is ConSE's own weighting bit for bit (every result stored before
it reproduces); any other temperature tempers the top-k probabilities as ``softmax(logits / T)``
would, over the same classes; the encoder's id says which (image-embedding caches are keyed by
it); one default on both sides; bad values are refused by name.
"""

from __future__ import annotations

import numpy as np
import pytest

from craft_e.runtime.encoders import conse
from craft_e.runtime.grounding import settings as grounding_settings
from craft_e.runtime.grounding.settings import GroundingSettings


def _probs(rng: np.random.Generator, n: int = 5, classes: int = 40) -> np.ndarray:
    logits = rng.normal(scale=3.0, size=(n, classes))
    e = np.exp(logits - logits.max(axis=1, keepdims=True))
    return (e / e.sum(axis=1, keepdims=True)).astype(np.float32)


def test_temperature_one_is_conse_own_weighting_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    probs, emb = _probs(rng), rng.normal(size=(40, 8)).astype(np.float32)
    # ConSE as written before the temperature: the top-k probabilities, renormalised, as weights
    p = probs.astype(np.float64)
    idx = np.argpartition(-p, 9, axis=1)[:, :10]
    w = np.take_along_axis(p, idx, axis=1)
    w = w / np.maximum(w.sum(axis=1, keepdims=True), 1e-12)
    ref = np.einsum("nk,nkd->nd", w, emb.astype(np.float64)[idx])
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    np.testing.assert_array_equal(conse.conse_embed(probs, emb, 10), ref.astype(np.float32))
    np.testing.assert_array_equal(conse.conse_embed(probs, emb, 10, 1.0), ref.astype(np.float32))


def test_a_temperature_tempers_the_logits_over_the_same_top_k() -> None:
    rng = np.random.default_rng(1)
    logits = rng.normal(scale=3.0, size=(4, 30))
    probs = np.exp(logits) / np.exp(logits).sum(axis=1, keepdims=True)
    emb = rng.normal(size=(30, 6))
    for t in (0.5, 2.0, 4.0):
        tempered = np.exp(logits / t)  # the classifier's softmax at temperature t, unnormalised
        top = np.argsort(-logits, axis=1)[:, :10]  # the same classes at any t
        w = np.take_along_axis(tempered, top, axis=1)
        w /= w.sum(axis=1, keepdims=True)
        ref = np.einsum("nk,nkd->nd", w, emb[top])
        ref /= np.linalg.norm(ref, axis=1, keepdims=True)
        np.testing.assert_allclose(conse.conse_embed(probs, emb, 10, t), ref, atol=1e-6)
    # a higher temperature spreads the weight: the embedding moves away from the top class's
    top1 = emb[np.argmax(logits, axis=1)]
    top1 = top1 / np.linalg.norm(top1, axis=1, keepdims=True)
    near = [float(np.mean(np.sum(conse.conse_embed(probs, emb, 10, t) * top1, axis=1))) for t in (1.0, 2.0, 4.0)]
    assert near[0] > near[1] > near[2]


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_a_bad_temperature_is_refused_by_name(bad: float) -> None:
    with pytest.raises(ValueError, match="temperature must be a finite number > 0"):
        conse.check_temperature(bad)
    with pytest.raises(ValueError, match="temperature must be a finite number > 0"):
        conse.conse_embed(np.full((1, 3), 1 / 3), np.eye(3), 2, bad)
    with pytest.raises(ValueError, match="--conse-temperature"):
        GroundingSettings.of(conse_temperature=bad)


def test_one_default_on_both_sides_and_results_record_it() -> None:
    assert conse.DEFAULT_CONSE_TEMPERATURE == grounding_settings.DEFAULT_CONSE_TEMPERATURE == 2.0
    assert GroundingSettings().conse_temperature == conse.DEFAULT_CONSE_TEMPERATURE
    assert GroundingSettings().energy_dict()["conse_temperature"] == 2.0
    # at 1 a result reads as every result stored before the temperature
    assert "conse_temperature" not in GroundingSettings(conse_temperature=1.0).energy_dict()


def test_the_encoder_says_its_temperature_and_the_evaluations_build_it() -> None:
    from craft_e.runtime.evaluation.sim_eval import default_encoder

    tempered = conse.ConSEImageEncoder(threads=1)
    plain = conse.ConSEImageEncoder(threads=1, temperature=1.0)
    assert tempered.temperature == 2.0 and tempered.id == plain.id + "+t2"  # caches keyed by id never mix them
    assert default_encoder(1, temperature=1.0).id == default_encoder(1).id.removesuffix("+t2")
    with pytest.raises(ValueError, match="temperature must be"):
        conse.ConSEImageEncoder(threads=1, temperature=0.0)
    probs = _probs(np.random.default_rng(2), classes=1000)
    np.testing.assert_array_equal(tempered.embed_probabilities(probs),
                                  conse.conse_embed(probs, tempered.class_embeddings, 10, 2.0))
    np.testing.assert_array_equal(plain.embed_probabilities(probs),
                                  conse.conse_embed(probs, plain.class_embeddings, 10))
