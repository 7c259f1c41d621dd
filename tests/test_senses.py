"""Names read in their sense (``grounding/senses.py``): the mix, where glosses come from, and the
evaluations giving every method the same ones."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from craft_e.paths import KB_DIR
from craft_e.runtime.evaluation.common import read_senses, vocabulary_senses
from craft_e.runtime.evaluation.methods import build_grounders, load_methods, select_methods
from craft_e.runtime.grounding import senses
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.grounding.senses import embed_glosses, read_in_sense
from craft_e.runtime.grounding.settings import DEFAULT_SENSE_WEIGHT, GroundingSettings
from craft_e.runtime.kb.bundle import load_bundle


class FixedEncoder:
    """A text encoder that knows a few texts (its calls are counted)."""

    def __init__(self, table: dict[str, list[float]]) -> None:
        self.table = table
        self.calls: list[list[str]] = []

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        self.calls.append(list(texts))
        return np.array([self.table[t] for t in texts], dtype=np.float32)


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_a_glossed_name_is_the_unit_mean_of_its_two_embeddings_and_others_stay() -> None:
    names = np.array([[2.0, 0.0, 0.0], [0.0, 3.0, 0.0]], dtype=np.float32)
    encoder = FixedEncoder({"a hand tool": [0.0, 0.0, 5.0]})
    out = read_in_sense(names, ["a hand tool", None], 0.5, encoder.embed)
    np.testing.assert_allclose(out[0], unit(np.array([0.5, 0.0, 0.5])), atol=1e-6)
    np.testing.assert_array_equal(out[1], names[1])  # no gloss: the name as given
    np.testing.assert_allclose(read_in_sense(names, ["a hand tool", None], 0.25, encoder.embed)[0],
                               unit(np.array([0.75, 0.0, 0.25])), atol=1e-6)


def test_weight_zero_or_no_gloss_leaves_the_names_and_embeds_nothing() -> None:
    names = np.eye(2, dtype=np.float32)
    assert read_in_sense(names, ["x", "y"], 0.0, None) is names
    assert read_in_sense(names, [None, None], 0.5, None) is names
    with pytest.raises(ValueError, match="needs the bundle's text encoder"):
        read_in_sense(names, ["x", None], 0.5, None)
    with pytest.raises(ValueError, match="does not embed into the bundle's space"):
        read_in_sense(names, ["x", None], 0.5, FixedEncoder({"x": [1.0, 0.0, 0.0]}).embed)


def test_glosses_are_embedded_once_per_process_and_kept_on_disk_for_a_known_encoder(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(senses, "_EMBEDDED", {})
    encoder = FixedEncoder({"a hand tool": [0.0, 0.0, 5.0], "a fruit": [1.0, 0.0, 0.0]})
    glosses = ["a hand tool", "a fruit"]
    # a stand-in encoder: memoized per process, never written to disk
    first = embed_glosses(glosses, lambda: encoder)  # type: ignore[arg-type,return-value]
    again = embed_glosses(glosses, lambda: encoder)  # type: ignore[arg-type,return-value]
    assert again is first and encoder.calls == [glosses]
    assert not list(tmp_path.iterdir())
    # an encoder known by its id and weights: computed once, then read from disk by a later process
    known = ("minilm-l6-v2", "ab" * 32)
    stored = embed_glosses(glosses, lambda: encoder, known, tmp_path)  # type: ignore[arg-type,return-value]
    path = senses.senses_cache_path(tmp_path, *known, glosses)
    assert path.is_file() and not list(tmp_path.glob("*.tmp"))
    monkeypatch.setattr(senses, "_EMBEDDED", {})  # a new process

    def no_encoder() -> FixedEncoder:
        raise AssertionError("the cache should have answered")

    np.testing.assert_array_equal(embed_glosses(glosses, no_encoder, known, tmp_path), stored)  # type: ignore[arg-type]
    # another encoder's (or another list's) file is not trusted: recomputed
    monkeypatch.setattr(senses, "_EMBEDDED", {})
    other = ("minilm-l6-v2", "cd" * 32)
    path.rename(senses.senses_cache_path(tmp_path, *other, glosses))
    calls = len(encoder.calls)
    embed_glosses(glosses, lambda: encoder, known, tmp_path)  # type: ignore[arg-type,return-value]
    assert len(encoder.calls) == calls + 1
    # a damaged file (a crash mid-write by an older version, a full disk) is recomputed, not an error
    monkeypatch.setattr(senses, "_EMBEDDED", {})
    path.write_bytes(path.read_bytes()[:40])
    np.testing.assert_array_equal(embed_glosses(glosses, lambda: encoder, known, tmp_path), stored)  # type: ignore[arg-type,return-value]
    assert len(encoder.calls) == calls + 2 and path.stat().st_size > 40


def test_the_weight_is_validated_and_stored_only_when_on() -> None:
    assert GroundingSettings().sense_weight == DEFAULT_SENSE_WEIGHT == 0.5
    assert GroundingSettings.of(sense_weight=None).sense_weight == DEFAULT_SENSE_WEIGHT
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="--sense-weight"):
            GroundingSettings.of(sense_weight=bad)
    assert GroundingSettings().energy_dict()["sense_weight"] == 0.5
    assert "sense_weight" not in GroundingSettings(sense_weight=0.0).energy_dict()


def test_the_grounder_reads_the_bundles_glosses_or_the_callers() -> None:
    bundle = load_bundle(KB_DIR / "craft-e-default", check_encoder=False)
    vocab = ["remote", "cup", "knife"]
    alone = Grounder(bundle, GroundingSettings(vocabulary=vocab, sense_weight=0.0, hubness=False))
    sensed = Grounder(bundle, GroundingSettings(vocabulary=vocab, hubness=False))
    assert not alone.senses_active and sensed.senses_active and sensed.senses_read == 3
    encoder = sensed._encoder()
    glosses = [bundle.index.gloss(n) for n in vocab]
    assert all(glosses)
    names = unit(np.asarray(encoder.embed(vocab), dtype=np.float64))
    expected = unit(0.5 * names + 0.5 * unit(np.asarray(encoder.embed([str(g) for g in glosses]), np.float64)))
    np.testing.assert_allclose(sensed._obj_emb_t.T, expected, atol=1e-5)
    np.testing.assert_allclose(alone._obj_emb_t.T, names, atol=1e-5)
    # a caller's glosses replace the bundle's; a name the caller has none for is read alone
    mine = Grounder(bundle, GroundingSettings(vocabulary=vocab, hubness=False), senses={"cup": "a teacup"})
    assert mine.senses_read == 1
    np.testing.assert_allclose(mine._obj_emb_t.T[[0, 2]], names[[0, 2]], atol=1e-5)
    np.testing.assert_allclose(
        mine._obj_emb_t.T[1], unit(0.5 * names[1] + 0.5 * unit(np.asarray(encoder.embed(["a teacup"])[0], np.float64))),
        atol=1e-5)


def test_a_sense_moves_a_crop_of_the_glossed_kind_to_its_name() -> None:
    """A crop that lies where a gloss's words lie (here: exactly on the gloss of "remote") is given
    to "remote" more surely when names are read in their sense."""
    bundle = load_bundle(KB_DIR / "craft-e-default", check_encoder=False)
    vocab = ["remote", "cup", "knife", "marker", "mug"]
    alone = Grounder(bundle, GroundingSettings(vocabulary=vocab, sense_weight=0.0, hubness=False))
    sensed = Grounder(bundle, GroundingSettings(vocabulary=vocab, hubness=False))
    crop = np.asarray(sensed._encoder().embed([str(bundle.index.gloss("remote"))]), dtype=np.float32)
    verb = alone.verbs[0]
    assert sensed.energies(verb, crop).p_obj[0, 0] > alone.energies(verb, crop).p_obj[0, 0]


def test_every_evaluated_method_reads_the_vocabularys_senses() -> None:
    """ConceptNet's bundle records no glosses (its objects were not asked in a sense), yet in an
    evaluation it reads the same senses as CRAFT-E: perception is the same for every method."""
    senses = vocabulary_senses()
    assert senses["remote"].startswith("a hand-held remote control")
    runnable, _ = load_methods(select_methods(["CRAFT-E", "CRAFT"]))
    vocab = ["remote", "cup", "knife"]
    grounders = build_grounders(runnable, GroundingSettings(), vocab)
    craft_e, craft = grounders["CRAFT-E"], grounders["CRAFT"]
    assert load_bundle(KB_DIR / "conceptnet", check_encoder=False).index.gloss("remote") is None
    assert craft_e.senses_read == craft.senses_read == 3
    np.testing.assert_allclose(craft._obj_emb_t, craft_e._obj_emb_t, atol=1e-6)
    off = build_grounders(runnable, GroundingSettings(sense_weight=0.0), vocab)
    assert not off["CRAFT"].senses_active and not off["CRAFT-E"].senses_active


def test_read_senses_skips_names_without_a_gloss_and_comments(tmp_path: Path) -> None:
    path = tmp_path / "objects.txt"
    path.write_text("# a comment\ncup\ta small open drinking container\nknife\n\nRemote \t a remote control \n",
                    encoding="utf-8")
    assert read_senses(path) == {"cup": "a small open drinking container", "remote": "a remote control"}


def test_a_missing_vocabulary_names_the_file_and_the_way_around_it(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("craft_e.paths.VOCAB_DIR", tmp_path)
    with pytest.raises(FileNotFoundError, match=r"default_objects\.txt: the vocabulary's glosses are missing.*"
                                                r"--sense-weight 0"):
        vocabulary_senses()
