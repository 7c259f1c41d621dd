"""Perceptual-noise robustness: the noise functions, the perturbed encoder, a tiny sweep, the CLI."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from runtime_fixtures import RuntimeKBs, conse_fixture, runtime_kbs_fixture  # noqa: F401
from typer.testing import CliRunner

from craft_e.runtime.evaluation.imagenet import evaluate_imagenet
from craft_e.runtime.evaluation.methods import MethodSpec
from craft_e.runtime.evaluation.robustness import (
    NOISE_KINDS,
    NoiseKind,
    PerturbedImageEncoder,
    add_gaussian_noise,
    evaluate_robustness,
    gaussian_blur,
    jitter_box,
    noise_rng,
    parse_levels,
    perturb_grasp_scores,
    perturb_image,
    random_crop,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def photo(seed: int = 0, shape: tuple[int, int] = (300, 400)) -> npt.NDArray[np.uint8]:
    """A synthetic RGB image with structure at several scales."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    base = 128 + 60 * np.sin(xx / 7.0) * np.cos(yy / 11.0)
    img = base[..., None] + rng.normal(0, 20, size=(*shape, 3))
    out: npt.NDArray[np.uint8] = np.clip(img, 0, 255).astype(np.uint8)
    return out


def iou(a: Sequence[float], b: Sequence[float]) -> float:
    ax1, ay1, bx1, by1 = a[0] + a[2], a[1] + a[3], b[0] + b[2], b[1] + b[3]
    iw = max(0.0, min(ax1, bx1) - max(a[0], b[0]))
    ih = max(0.0, min(ay1, by1) - max(a[1], b[1]))
    inter = iw * ih
    return inter / (a[2] * a[3] + b[2] * b[3] - inter)


# -- noise functions -------------------------------------------------------------------------


def test_level_zero_is_the_identity_and_draws_nothing() -> None:
    img = photo()
    for kind in NOISE_KINDS:
        rng = np.random.default_rng(5)
        out = perturb_image(img, kind, 0.0, rng)
        assert out is not img and np.array_equal(out, img)
        assert rng.random() == np.random.default_rng(5).random()  # no draw consumed
    rng = np.random.default_rng(5)
    assert np.array_equal(add_gaussian_noise(img, 0.0, rng), img)
    assert np.array_equal(gaussian_blur(img, 0.0), img)
    assert np.array_equal(random_crop(img, 0.0, rng), img)
    assert jitter_box((3.0, 4.0, 50.0, 20.0), 0.0, rng, (400, 300)) == (3.0, 4.0, 50.0, 20.0)
    scores = [0.2, 0.9, 1.0]
    assert perturb_grasp_scores(scores, 0.0, rng).tolist() == scores
    assert rng.random() == np.random.default_rng(5).random()


@pytest.mark.parametrize(("kind", "level"), [("gaussian", 16.0), ("blur", 2.0), ("crop", 0.5)])
def test_noise_is_deterministic_for_a_seed(kind: str, level: float) -> None:
    img = photo()
    a = perturb_image(img, kind, level, noise_rng(0, kind, level, b"img"))  # type: ignore[arg-type]
    b = perturb_image(img, kind, level, noise_rng(0, kind, level, b"img"))  # type: ignore[arg-type]
    assert np.array_equal(a, b) and not np.array_equal(a, img) if a.shape == img.shape else np.array_equal(a, b)
    if kind != "blur":  # blur has no randomness; the others change with the seed or the image key
        c = perturb_image(img, kind, level, noise_rng(1, kind, level, b"img"))  # type: ignore[arg-type]
        d = perturb_image(img, kind, level, noise_rng(0, kind, level, b"other"))  # type: ignore[arg-type]
        assert not (c.shape == a.shape and np.array_equal(c, a))
        assert not (d.shape == a.shape and np.array_equal(d, a))
    g = np.random.default_rng(3)
    assert np.array_equal(perturb_grasp_scores([0.5, 0.7], 0.1, g), perturb_grasp_scores([0.5, 0.7], 0.1,
                                                                                          np.random.default_rng(3)))


def test_gaussian_noise_has_the_requested_sigma_and_blur_smooths() -> None:
    grey = np.full((200, 200, 3), 128, np.uint8)
    noisy = add_gaussian_noise(grey, 16.0, np.random.default_rng(0))
    assert abs(float(noisy.astype(float).std()) - 16.0) < 0.5
    img = photo()
    sharp = np.abs(np.diff(img.astype(float), axis=1)).mean()
    assert np.abs(np.diff(gaussian_blur(img, 4.0).astype(float), axis=1)).mean() < 0.3 * sharp
    # noise and blur act at the encoder's scale: short side 256
    out = perturb_image(photo(shape=(600, 800)), "gaussian", 8.0, np.random.default_rng(0))
    assert out.shape == (256, 341, 3)


def test_jitter_box_keeps_the_area_fraction_inside_the_box() -> None:
    rng = np.random.default_rng(0)
    box = (40.0, 30.0, 120.0, 80.0)
    for frac in (0.1, 0.25, 0.5, 0.9):
        for _ in range(20):
            j = jitter_box(box, frac, rng, (640, 480))
            assert iou(box, j) == pytest.approx(1 - frac, abs=1e-9)
            assert j[0] >= box[0] and j[1] >= box[1]
            assert j[0] + j[2] <= box[0] + box[2] + 1e-9 and j[1] + j[3] <= box[1] + box[3] + 1e-9
            assert j[2] / j[3] == pytest.approx(box[2] / box[3])
    clipped = jitter_box((-50.0, -50.0, 100.0, 100.0), 0.5, rng, (640, 480))
    assert clipped[0] >= 0 and clipped[1] >= 0
    with pytest.raises(ValueError, match=r"\[0, 1\)"):
        jitter_box(box, 1.0, rng, (640, 480))
    with pytest.raises(ValueError, match="outside"):
        jitter_box((700.0, 0.0, 10.0, 10.0), 0.5, rng, (640, 480))
    crop = random_crop(photo(), 0.75, rng)
    assert crop.shape[0] * crop.shape[1] == pytest.approx(0.25 * 300 * 400, rel=0.03)


def test_grasp_score_noise_is_clipped_and_keeps_order_of_candidates() -> None:
    scores = np.linspace(0, 1, 50)
    out = perturb_grasp_scores(scores, 0.3, np.random.default_rng(0))
    assert out.shape == (50,) and out.min() >= 0.0 and out.max() <= 1.0 and not np.array_equal(out, scores)
    with pytest.raises(ValueError):
        perturb_grasp_scores(scores, -0.1, np.random.default_rng(0))


def test_parse_levels() -> None:
    assert parse_levels(["gaussian=8,16", "crop=0.5,0"]) == {"gaussian": (0.0, 8.0, 16.0), "crop": (0.0, 0.5)}
    for bad in ("noise=1", "gaussian", "blur=a,b", "crop=0,1.0", "gaussian=-1", "blur="):
        with pytest.raises(ValueError):
            parse_levels([bad])


# -- the perturbed encoder -------------------------------------------------------------------


class MeanColourEncoder:
    """A stand-in encoder: mean colour + size as a 4-d vector; counts the crops it embeds."""

    id = "mean-colour"
    text_encoder_id = "toy"
    dim = 4

    def __init__(self) -> None:
        self.calls = 0

    def embed_images(self, crops: Sequence[npt.NDArray[np.uint8]], batch_size: int = 16) -> npt.NDArray[np.float32]:
        self.calls += len(crops)
        return np.array([[*c.reshape(-1, 3).mean(axis=0), c.shape[0] * c.shape[1]] for c in crops], np.float32)


def test_perturbed_encoder_is_per_image_deterministic_and_memoized() -> None:
    base = MeanColourEncoder()
    a, b = photo(1), photo(2)
    enc = PerturbedImageEncoder(base, "crop", 0.5, seed=0)
    both = enc.embed_images([a, b, a])
    assert base.calls == 2 and np.array_equal(both[0], both[2])  # a perturbed once, memoized
    alone = PerturbedImageEncoder(MeanColourEncoder(), "crop", 0.5, seed=0).embed_images([b])
    assert np.array_equal(alone[0], both[1])  # noise depends on the image, not the batch or order
    other = PerturbedImageEncoder(MeanColourEncoder(), "crop", 0.5, seed=1).embed_images([b])
    assert not np.array_equal(other[0], both[1])
    assert PerturbedImageEncoder(base, "gaussian", 0.0).id == base.id  # clean level shares the cache
    draws: list[tuple[NoiseKind, float, int]] = [("gaussian", 8, 0), ("gaussian", 16, 0), ("gaussian", 8, 1),
                                                 ("blur", 8, 0), ("blur", 8, 1)]
    ids = [PerturbedImageEncoder(base, k, v, s).id for k, v, s in draws]
    assert len(set(ids)) == 4 and ids[3] == ids[4]  # blur has no randomness: the seed is not in its id
    with pytest.raises(ValueError, match="crop level"):
        PerturbedImageEncoder(base, "crop", 1.0)
    with pytest.raises(ValueError, match="unknown noise kind"):
        PerturbedImageEncoder(base, "jpeg", 10)  # type: ignore[arg-type]


# -- a tiny sweep ----------------------------------------------------------------------------


def test_tiny_robustness_run(runtime_kbs: RuntimeKBs, conse: Any, tmp_path: Path) -> None:
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps({"cut": ["cleaver", "hatchet"], "eat": ["banana", "orange", "pizza"]}))
    methods = [MethodSpec("CRAFT-E", "", runtime_kbs.kb), MethodSpec("alignment-only", "", runtime_kbs.kb, beta=0.0)]
    kwargs: dict[str, Any] = {"methods": methods, "episodes": 8, "seed": 0, "pool": list(runtime_kbs.objects),
                              "encoder": conse, "cache_dir": tmp_path / "enc"}
    rep = evaluate_robustness(labels, levels={"gaussian": [0, 48], "crop": [0.6]}, noise_seeds=[0], **kwargs)
    assert rep.levels == {"gaussian": [0.0, 48.0], "crop": [0.0, 0.6]}
    assert rep.methods == ["CRAFT-E", "alignment-only"]
    for kind in rep.levels:
        for method in rep.methods:
            rows = rep.metrics[kind][method]
            assert len(rows) == 2
            assert all(0.0 <= r[m] <= 1.0 for r in rows for m in ("top1", "top2", "mrr", "ndcg"))
        assert all(r is not None and 0.0 <= r <= 1.0 for r in rep.recognition[kind])
    # the recognition row ranks p(o | r) as the grounder reads it (senses, hubness), on the photos
    # of the pool's classes the bundle knows
    from craft_e.runtime.evaluation.common import vocabulary_senses
    from craft_e.runtime.evaluation.imagenet import embed_dataset_images, load_dataset
    from craft_e.runtime.grounding.grounder import Grounder
    from craft_e.runtime.grounding.settings import GroundingSettings
    from craft_e.runtime.kb.bundle import load_bundle

    data = load_dataset()
    bundle = load_bundle(runtime_kbs.kb, check_encoder=False)
    known = sorted(data.class_index[c] for c in runtime_kbs.objects if c in bundle.object_index)
    names = [data.classes[c] for c in known]
    images = [i for c in known for i in data.class_images[c]]
    truth = [k for k, c in enumerate(known) for _ in data.class_images[c]]
    grounder = Grounder(bundle, GroundingSettings(vocabulary=names), senses=vocabulary_senses())
    p = grounder.image_hypotheses(embed_dataset_images(data, images, conse, tmp_path / "enc"))
    assert rep.recognition["gaussian"][0] == pytest.approx(float(np.mean(p.argmax(axis=1) == truth)))
    # level 0 is exactly the plain protocol
    clean = {r.name: r.metrics for r in evaluate_imagenet(labels, **kwargs).results}
    assert rep.metrics["gaussian"]["CRAFT-E"][0] == pytest.approx(clean["CRAFT-E"])
    assert rep.metrics["crop"]["alignment-only"][0] == pytest.approx(clean["alignment-only"])
    # one embedding cache file per (kind, level, seed) besides the clean one; a rerun reads them
    files = sorted(p.name for p in (tmp_path / "enc").glob("images.*.safetensors"))
    assert len(files) == 3 and sum(f.startswith("images.noise_gaussian_48_seed0") for f in files) == 1
    again = evaluate_robustness(labels, levels={"gaussian": [0, 48], "crop": [0.6]}, noise_seeds=[0], **kwargs)
    assert again.to_dict() == rep.to_dict()
    # several noise seeds: the mean of the single-seed runs, their spread reported
    seeds = evaluate_robustness(labels, levels={"gaussian": [48]}, noise_seeds=[0, 1], **kwargs)
    one = evaluate_robustness(labels, levels={"gaussian": [48]}, noise_seeds=[1], **kwargs)
    a, b = rep.metrics["gaussian"]["CRAFT-E"][1], one.metrics["gaussian"]["CRAFT-E"][1]
    assert seeds.metrics["gaussian"]["CRAFT-E"][1]["mrr"] == pytest.approx((a["mrr"] + b["mrr"]) / 2)
    assert seeds.spread["gaussian"]["CRAFT-E"][1]["mrr"] == pytest.approx(abs(a["mrr"] - b["mrr"]) / 2)
    assert seeds.spread["gaussian"]["CRAFT-E"][0]["mrr"] == 0.0 and " ±" in seeds.to_markdown()
    seeds.plot(tmp_path / "seeds.png")
    png = rep.plot(tmp_path / "plot.png")
    assert png.read_bytes()[:8] == PNG_MAGIC
    md = rep.to_markdown()
    assert "#### gaussian" in md and "| CRAFT-E |" in md and "σ=48" in md and "keep 40%" in md
    json.dumps(rep.to_dict(), allow_nan=False)


def test_cli_robustness_imagenet(runtime_kbs: RuntimeKBs, tmp_path: Path) -> None:
    from craft_e.runtime.cli.main import app

    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps({"cut": ["cleaver", "hatchet"], "play": ["violin", "flute", "drum"]}))
    classes = tmp_path / "classes.txt"
    classes.write_text("\n".join(runtime_kbs.objects))
    (tmp_path / "no-baselines").mkdir()  # an empty folder of bundles: the baselines are skipped
    args = ["eval", "robustness", "imagenet", "--labels", str(labels), "--kb", str(runtime_kbs.kb),
            "--kb-dir", str(tmp_path / "no-baselines"), "--classes", str(classes), "--episodes", "5",
            "--levels", "blur=4", "--no-cache", "--threads", "1"]
    out = [tmp_path / "r.json", tmp_path / "r.png", tmp_path / "r.md"]
    r = CliRunner().invoke(app, [*args, "--json", str(out[0]), "--plot", str(out[1]), "--markdown", str(out[2])])
    assert r.exit_code == 0, r.output
    data = json.loads(out[0].read_text())
    assert data["levels"] == {"blur": [0.0, 4.0]} and {"CRAFT", "direct-LLM"} <= {
        s["method"] for s in data["skipped_methods"]}
    assert out[1].read_bytes()[:8] == PNG_MAGIC and "#### blur" in out[2].read_text()
    bad = CliRunner().invoke(app, [*args[:-5], "--levels", "fog=1"])
    assert bad.exit_code == 2 and "KIND" in bad.output


def test_craft_eval_has_the_robustness_group() -> None:
    from craft_e.runtime.cli.main import app

    r = CliRunner().invoke(app, ["eval", "robustness", "imagenet", "--help"])
    assert r.exit_code == 0 and "--levels" in r.output
