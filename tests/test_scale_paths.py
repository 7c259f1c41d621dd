"""The fast paths added for large KBs (issue 14 item 4) give exactly what the slow ones gave.

Shipped bundles must stay byte-identical, so each replacement is checked against the code it
replaced: the indented graph.json writer against ``json.dumps``, the open-world neighbour search
against a full stable argsort, the diagnostics' margin ranking against ``ranked_objects``, and
the embedding cache's batched index against what a build reads back.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import craft_e.compiler.embed as embed
from craft_e.compiler.cache import EmbeddingIndex
from craft_e.compiler.graph import indented_json
from craft_e.runtime.grounding.open_world import _top_sorted
from craft_e.runtime.kb.diagnostics import discrimination_diagnostics, ranked_objects


def _random_json(rng: np.random.Generator, depth: int = 0) -> Any:
    kind = int(rng.integers(0, 8 if depth < 4 else 5))
    if kind == 0:
        return "".join(rng.choice(list('ab "\\\n\té€→\x01'), size=int(rng.integers(0, 6))))
    if kind == 1:
        return float(rng.choice([0.0, -0.0, 1e-7, 0.1, 1e300, float(rng.normal())]))
    if kind == 2:
        return int(rng.integers(-5, 5))
    if kind == 3:
        return [None, True, False][int(rng.integers(0, 3))]
    if kind == 4:
        return [f"s{i}" for i in range(int(rng.integers(0, 3)))]
    if kind in (5, 6):
        return {f"k{int(rng.integers(0, 9))}": _random_json(rng, depth + 1)
                for _ in range(int(rng.integers(0, 4)))}
    return [_random_json(rng, depth + 1) for _ in range(int(rng.integers(0, 4)))]


def test_indented_json_is_json_dumps_byte_for_byte() -> None:
    rng = np.random.default_rng(0)
    for _ in range(500):
        value = {"nodes": _random_json(rng), "edges": [_random_json(rng) for _ in range(3)]}
        assert indented_json(value) == json.dumps(value, indent=1, sort_keys=True, ensure_ascii=False)
    for odd in ({1: "non-string key"}, [float("nan"), float("inf")], (1, 2)):
        assert indented_json(odd) == json.dumps(odd, indent=1, sort_keys=True, ensure_ascii=False)


def test_top_sorted_is_the_stable_argsort_prefix() -> None:
    rng = np.random.default_rng(1)
    for trial in range(300):
        n, m = int(rng.integers(1, 15)), int(rng.integers(1, 60))
        sims = (rng.choice([0.1, 0.2, 0.5, -0.3], size=(n, m)) if trial % 2
                else rng.normal(size=(n, m)))  # many ties, then none
        k = int(rng.integers(1, 70))
        want = np.argsort(-sims, axis=1, kind="stable")[:, :k]
        np.testing.assert_array_equal(_top_sorted(sims, k), want)


def test_margins_rank_like_ranked_objects() -> None:
    rng = np.random.default_rng(2)
    objects = [f"object {i}" for i in rng.permutation(40)]
    energy = rng.choice([-1.0, -0.5, -0.5, 0.0, 1.0], size=(6, 40)).astype(np.float32)
    w_vp, w_po = np.ones((6, 2), np.float32), np.ones((2, 40), np.float32)
    verbs = [f"verb {i}" for i in range(6)]
    diag = discrimination_diagnostics(energy, w_vp, w_po, verbs, ["a", "b"], objects, margin_rank=10)
    for v, verb in enumerate(verbs):
        order = ranked_objects(energy[v], objects)
        expected = round(float(energy[v, order[9]] - energy[v, order[0]]), 6) + 0.0
        assert diag["margins"][verb] == expected


class _Encoder:
    def embed(self, texts: list[str]) -> np.ndarray[Any, np.dtype[np.float32]]:
        out = np.zeros((len(texts), 4), np.float32)
        out[:, 0] = [len(t) for t in texts]
        return out


def test_embedding_index_written_in_batches(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(embed, "load_text_encoder", lambda _id: _Encoder())
    monkeypatch.setattr(embed, "INDEX_BATCH", 20)
    texts = [f"text {'x' * i}" for i in range(50)]
    first = embed.EmbeddingCache(tmp_path, "fake")
    vectors = first.embed(texts)
    assert first.misses == 50
    assert len(EmbeddingIndex(tmp_path / "fake").read()) == 50  # the last partial batch too
    again = embed.EmbeddingCache(tmp_path, "fake")
    np.testing.assert_array_equal(again.embed(texts), vectors)
    assert (again.hits, again.misses) == (50, 0)
