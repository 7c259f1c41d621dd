"""ConSE's ImageNet class names read in their sense (``encoders/conse.py``): the glosses file, the
cached mix, the encoder's identity, and one weight reading both sides of the cosine."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from craft_e.paths import KB_DIR
from craft_e.runtime.encoders import conse
from craft_e.runtime.encoders.conse import (
    DEFAULT_CLASS_SENSE_WEIGHT,
    check_sense_weight,
    imagenet_class_glosses,
    imagenet_class_names,
    load_class_embeddings,
    parse_class_glosses,
)
from craft_e.runtime.encoders.text import EncoderError, sense_mean
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.grounding.hubness import HUBNESS_K, name_hubness, reference_for
from craft_e.runtime.grounding.settings import DEFAULT_SENSE_WEIGHT, GroundingSettings
from craft_e.runtime.kb.bundle import load_bundle

ROOT = Path(__file__).resolve().parent.parent


class HashEncoder:
    """A text encoder whose vector of a text is fixed by its hash (its batched calls are counted)."""

    def __init__(self) -> None:
        self.batches = 0

    def embed_batched(self, texts: Sequence[str]) -> np.ndarray:
        self.batches += 1
        seeds = [int(hashlib.sha256(t.encode()).hexdigest()[:8], 16) for t in texts]
        return np.stack([np.random.default_rng(s).normal(size=8) for s in seeds]).astype(np.float32)


def test_every_class_has_its_own_wordnet_sense_in_logit_order() -> None:
    glosses = imagenet_class_glosses()
    names = imagenet_class_names()
    assert len(glosses) == len(names) == 1000 and all(glosses)
    cranes = [g for n, g in zip(names, glosses, strict=True) if n == "crane"]
    assert len(cranes) == 2 and "bird" in cranes[0] and "heavy objects" in cranes[1]
    lines = (ROOT / "runtime" / "encoders" / "imagenet_glosses.tsv").read_text("utf-8").splitlines()
    wnids = [line.split("\t")[0] for line in lines]
    assert wnids == sorted(set(wnids))  # ImageNet-1k's logit order is its sorted synset ids


def test_a_damaged_glosses_file_names_the_line_and_the_fix() -> None:
    names = ("tench", "goldfish")
    assert parse_class_glosses("n1\ttench\ta fish\nn2\tgoldfish\ta small fish\n", names) == ("a fish", "a small fish")
    with pytest.raises(EncoderError, match=r"line 2: expected 'wnid<TAB>class name<TAB>gloss'.*make_class_glosses"):
        parse_class_glosses("n1\ttench\ta fish\nn2\tgoldfish\n", names)
    with pytest.raises(EncoderError, match=r"line 1: class 'goldfish', imagenet_classes.txt has 'tench'"):
        parse_class_glosses("n2\tgoldfish\ta small fish\nn1\ttench\ta fish\n", names)
    with pytest.raises(EncoderError, match="1 glosses, expected 2"):
        parse_class_glosses("n1\ttench\ta fish\n", names)


def test_the_classes_are_the_mix_of_their_cached_names_and_glosses(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    names, glosses = ("tench", "crane", "crane"), ("a fish", "a bird", "a machine")
    monkeypatch.setattr(conse, "imagenet_class_names", lambda: names)
    monkeypatch.setattr(conse, "imagenet_class_glosses", lambda: glosses)
    encoder = HashEncoder()
    kw = {"text_id": "hash", "text_sha256": "0" * 64, "text_encoder": encoder}
    bare = load_class_embeddings(tmp_path, sense_weight=0.0, **kw)
    assert encoder.batches == 1
    mixed = load_class_embeddings(tmp_path, sense_weight=0.5, **kw)
    assert encoder.batches == 2  # the names were read back from disk; only the glosses were embedded
    np.testing.assert_array_equal(mixed, sense_mean(bare, encoder.embed_batched(list(glosses)), 0.5))
    assert not np.allclose(mixed[1], mixed[2])  # the two cranes, one name, are two senses
    assert sorted(p.name.split(".")[0] for p in tmp_path.iterdir()) == ["imagenet1k-classes", "imagenet1k-glosses"]
    again = load_class_embeddings(tmp_path, sense_weight=0.5, **kw)
    assert encoder.batches == 3 and not list(tmp_path.glob("*.tmp"))  # 3: the reference embedding above
    np.testing.assert_array_equal(again, mixed)


def test_the_weight_is_checked_and_one_setting_reads_both_sides() -> None:
    assert DEFAULT_CLASS_SENSE_WEIGHT == DEFAULT_SENSE_WEIGHT
    for bad in (float("nan"), 1.5, -0.1):
        with pytest.raises(ValueError, match="sense_weight must be in"):
            check_sense_weight(bad)
    assert GroundingSettings().class_senses == DEFAULT_SENSE_WEIGHT
    assert GroundingSettings(sense_weight=0.0).class_senses == 0.0
    assert GroundingSettings(sense_weight=0.5, class_sense_weight=0.0).class_senses == 0.0
    assert GroundingSettings().energy_dict()["class_sense_weight"] == DEFAULT_SENSE_WEIGHT
    assert "class_sense_weight" not in GroundingSettings(sense_weight=0.0).energy_dict()  # as stored before


def test_the_hubness_reference_follows_the_class_names_reading() -> None:
    bundle = load_bundle(KB_DIR / "craft-e-default", check_encoder=False)
    enc = bundle.manifest.text_encoder
    bare, sensed = (reference_for(enc.id, enc.weights_sha256, w) for w in (0.0, 0.5))
    assert bare is not None and sensed is not None and not np.allclose(bare, sensed)
    np.testing.assert_array_equal(sensed, load_class_embeddings(sense_weight=0.5))
    vocab = ["knife", "cup", "clamp"]
    for w, reference in ((0.0, bare), (0.5, sensed)):
        g = Grounder(bundle, GroundingSettings(vocabulary=vocab, sense_weight=0.0, class_sense_weight=w))
        np.testing.assert_allclose(g._hubness, name_hubness(np.ascontiguousarray(g._obj_emb_t.T), reference, HUBNESS_K))


def test_the_encoder_says_how_it_reads_its_classes() -> None:
    sensed = conse.ConSEImageEncoder(threads=1, temperature=1.0)
    bare = conse.ConSEImageEncoder(threads=1, sense_weight=0.0, temperature=1.0)
    assert sensed.id == bare.id + "+senses0.5"  # an image-embedding cache keyed by id never mixes them
    np.testing.assert_array_equal(sensed.class_embeddings, load_class_embeddings(sense_weight=0.5))
    with pytest.raises(ValueError, match="sense_weight must be in"):
        conse.ConSEImageEncoder(threads=1, sense_weight=2.0)


def test_the_generator_writes_nothing_for_an_id_list_that_does_not_fit(tmp_path: Path) -> None:
    wnids = tmp_path / "wnids.txt"
    wnids.write_text("n01440764\nn01443537\n")
    out = tmp_path / "glosses.tsv"
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "make_class_glosses.py"), "--wnids", str(wnids),
                          "--wordnet", str(tmp_path), "--out", str(out)], capture_output=True, text=True)
    assert run.returncode != 0 and not out.exists()
    assert "data.noun" in run.stderr or "nothing written" in run.stderr
