"""ImageNet functional-grounding harness on the dev labels and tiny bundles (24 classes)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from runtime_fixtures import DEV_LABELS, RuntimeKBs, conse_fixture, runtime_kbs_fixture  # noqa: F401

from craft_e.runtime.evaluation.common import ndcg, reciprocal_rank, topk_accuracy
from craft_e.runtime.evaluation.imagenet import (
    LabelsError,
    evaluate_imagenet,
    load_dataset,
    load_labels,
    make_episodes,
)
from craft_e.runtime.evaluation.methods import MethodSpec, default_methods


def pool(kbs: RuntimeKBs) -> list[str]:
    return list(kbs.objects)


def methods(kbs: RuntimeKBs, tmp: Path) -> list[MethodSpec]:
    specs = default_methods(kbs.kb, kb_dir=tmp / "no-bundles")
    specs[2] = MethodSpec("direct-LLM", specs[2].description, kbs.direct)
    return specs


def test_unset_energy_weights_become_the_defaults_and_set_ones_are_kept() -> None:
    """Every command turns unset ``--beta``/``--gamma`` into numbers through ``energy_weights``
    (``craft eval`` via ``default_methods``, ``craft sim demo`` directly), so they cannot drift."""
    from craft_e.runtime.evaluation.methods import energy_weights
    from craft_e.runtime.grounding.settings import DEFAULT_BETA, DEFAULT_GAMMA

    assert energy_weights() == (DEFAULT_BETA, DEFAULT_GAMMA)
    assert energy_weights(1.0, None) == (1.0, DEFAULT_GAMMA)
    assert energy_weights(None, 0.0) == (DEFAULT_BETA, 0.0)  # 0 is a weight, not "unset"
    craft_e = default_methods(beta=2.0)[0]
    assert (craft_e.beta, craft_e.gamma) == (2.0, DEFAULT_GAMMA)


def test_dataset_has_two_photos_for_crane_and_cardigan() -> None:
    data = load_dataset()
    assert len(data.classes) == 216 and len(data.images) == 218
    assert len(data.class_images[data.class_index["crane"]]) == 2
    assert len(data.class_images[data.class_index["cardigan"]]) == 2


def test_labels_validation(tmp_path: Path) -> None:
    classes = load_dataset().classes
    labels = load_labels(DEV_LABELS, classes)
    assert "_comment" not in labels and labels["cut"] == ["cleaver", "hatchet"]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"cut": ["cleavr"]}))
    with pytest.raises(LabelsError, match="cleaver"):
        load_labels(bad, classes)
    bad.write_text("[1, 2]")
    with pytest.raises(LabelsError, match="expected an object"):
        load_labels(bad, classes)


def test_episodes_follow_the_protocol() -> None:
    data = load_dataset()
    labels = load_labels(DEV_LABELS, data.classes)
    sets, skipped = make_episodes(labels, data, episodes=50, seed=3)
    assert not skipped and len(sets) == 2 * len(labels)
    image_class = {i: c for c, ims in enumerate(data.class_images) for i in ims}
    for s in sets:
        classes = np.vectorize(image_class.get)(s.images)  # [E, 5]
        assert s.images.shape == (50, 5)
        assert all(len(set(row)) == 5 for row in classes.tolist())  # distinct classes
        if s.setting == "single":
            assert (s.relevant.sum(axis=1) == 1).all()
        else:  # 2-3 affording images among 5 (a verb with 2 affording classes can only have 2)
            assert set(s.relevant.sum(axis=1).tolist()) <= {2, 3}
    counts = {int(n) for s in sets if s.setting == "multi" for n in s.relevant.sum(axis=1)}
    assert counts == {2, 3}
    again, _ = make_episodes(labels, data, episodes=50, seed=3)
    assert all((a.images == b.images).all() for a, b in zip(sets, again, strict=True))
    fewer, _ = make_episodes({"cut": labels["cut"]}, data, episodes=50, seed=3)
    assert (fewer[0].images == sets[0].images).all()  # a verb's episodes do not depend on others
    other, _ = make_episodes(labels, data, episodes=50, seed=4)
    assert not (other[0].images == sets[0].images).all()


def test_chance_metrics_by_hand() -> None:
    from craft_e.runtime.evaluation.imagenet import chance_metrics

    rel = np.array([[True, False, False, False, False], [True, True, False, False, False],
                    [True, True, True, False, False]])  # fmt: skip
    got = chance_metrics(rel)
    np.testing.assert_allclose(got["top1"], [1 / 5, 2 / 5, 3 / 5], rtol=1e-6)
    np.testing.assert_allclose(got["top2"], [2 / 5, 1 - 3 / 10, 1 - 1 / 10], rtol=1e-6)
    # one relevant: mean of 1/i over 5 ranks; two: P(first at i) = (5-i)/10 -> 4/10 + 3/20 + 2/30 + 1/40
    np.testing.assert_allclose(got["mrr"][:2], [(1 + 1 / 2 + 1 / 3 + 1 / 4 + 1 / 5) / 5,
                                                0.4 + 0.15 + 2 / 30 + 1 / 40], rtol=1e-6)  # fmt: skip
    d = 1 / np.log2(np.arange(2, 7))
    np.testing.assert_allclose(got["ndcg"], [r / 5 * d.sum() / d[:r].sum() for r in (1, 2, 3)], rtol=1e-6)
    # a random ranking's expected metrics match a brute-force average over all orderings
    from itertools import permutations

    from craft_e.runtime.evaluation.common import ndcg as ndcg_of
    from craft_e.runtime.evaluation.common import reciprocal_rank as rr_of

    perms = np.array(list(permutations(range(5))), dtype=float)  # [120, 5] energies
    row = np.repeat(rel[1:2], len(perms), axis=0)
    assert float(rr_of(perms, row).mean()) == pytest.approx(float(got["mrr"][1]), rel=1e-6)
    assert float(ndcg_of(perms, row).mean()) == pytest.approx(float(got["ndcg"][1]), rel=1e-6)


def test_metrics_by_hand() -> None:
    energy = np.array([[0.1, 0.5, 0.3, 0.9, 0.7], [0.9, 0.2, 0.1, 0.5, 0.4]])
    rel = np.array([[False, False, True, False, False], [True, False, False, True, False]])
    np.testing.assert_allclose(topk_accuracy(energy, rel, 1), [0, 0])
    np.testing.assert_allclose(topk_accuracy(energy, rel, 2), [1, 0])
    np.testing.assert_allclose(reciprocal_rank(energy, rel), [1 / 2, 1 / 4])
    # row 2: relevant at ranks 4 and 5 -> (1/log2 5 + 1/log2 6) / (1 + 1/log2 3)
    want = (1 / np.log2(5) + 1 / np.log2(6)) / (1 + 1 / np.log2(3))
    np.testing.assert_allclose(ndcg(energy, rel), [1 / np.log2(3), want], rtol=1e-6)


def test_eval_is_deterministic_and_metrics_in_unit_interval(runtime_kbs: RuntimeKBs, conse: Any, tmp_path: Path) -> None:
    kwargs: dict[str, Any] = {"methods": methods(runtime_kbs, tmp_path), "episodes": 40, "seed": 0,
                              "pool": pool(runtime_kbs), "encoder": conse, "cache_dir": tmp_path / "enc"}
    a = evaluate_imagenet(DEV_LABELS, **kwargs)
    b = evaluate_imagenet(DEV_LABELS, **kwargs)  # second run reads the on-disk embedding cache
    assert a.to_dict() == b.to_dict()
    assert list((tmp_path / "enc").glob("images.*.safetensors"))
    names = [r.name for r in a.results]
    assert names == ["chance", "label oracle", "CRAFT-E", "direct-LLM", "alignment-only", "affordance-only"]
    by_name = {r.name: r.metrics for r in a.results}
    assert by_name["label oracle"] == {"top1": 1.0, "top2": 1.0, "mrr": 1.0, "ndcg": 1.0}
    assert by_name["chance"]["top1"] == pytest.approx(0.2) and by_name["chance"]["top2"] == pytest.approx(0.4)
    assert [s.name for s in a.skipped] == ["CRAFT"] and "bundle unavailable" in a.skipped[0].reason
    for r in a.results:
        assert set(r.metrics) == {"top1", "top2", "mrr", "ndcg"}
        assert all(0.0 <= v <= 1.0 for v in r.metrics.values())
        assert r.metrics["top1"] <= r.metrics["top2"]
        assert set(r.per_verb) == set(load_labels(DEV_LABELS, load_dataset().classes))
    by = {r.name: r.metrics for r in a.results}
    assert by["CRAFT-E"]["mrr"] > 0.5  # well above chance (~0.46 for 1 of 5) on easy dev labels
    c = evaluate_imagenet(DEV_LABELS, **{**kwargs, "seed": 1})
    assert c.to_dict()["methods"] != a.to_dict()["methods"]
    md = a.to_markdown()
    assert "| CRAFT-E |" in md and "CRAFT** skipped" in md
    assert "| chance |" in md and "| label oracle |" in md and "One photo per class" in md
    assert a.to_dict()["config"]["labels_sha256"]


def test_verbs_missing_from_a_bundle_use_the_flagged_fallback(runtime_kbs: RuntimeKBs, conse: Any, tmp_path: Path) -> None:
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps({"drink from": ["cup", "teapot"], "cut": ["cleaver"]}))
    rep = evaluate_imagenet(labels, methods=[MethodSpec("CRAFT-E", "", runtime_kbs.kb)], episodes=10,
                            pool=pool(runtime_kbs), encoder=conse, cache_dir=None)
    r = next(m for m in rep.results if m.name == "CRAFT-E")
    assert r.settings["open_vocab_verbs"] == ["drink from"] and "open-vocabulary" in r.notes[0]
