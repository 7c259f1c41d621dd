"""Fixtures of the runtime tests: tiny bundles built from hand-written test answers, encoders.

A test module imports the fixture functions it needs (``from runtime_fixtures import
runtime_kbs_fixture``); pytest registers them under their ``name=`` (``runtime_kbs``, ``conse``),
so test parameters do not shadow the imports. The answers in ``tests/fixtures/runtime_kb`` are test
data written for the project's prompts (6 verbs x 24 ImageNet objects), stored as records under
provider ``test-fixture`` in a temporary cache — never ``curated``, never in ``artifacts/``. The
bundles are built once per session with the compiler (tests may import it; the runtime may not),
sharing the compiler's git-ignored text-embedding cache so only a machine's first session embeds.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

FIXTURES = Path(__file__).resolve().parent / "fixtures"
RUNTIME_KB = FIXTURES / "runtime_kb"
DEV_LABELS = FIXTURES / "imagenet_dev_labels.json"
PROVIDER = "test-fixture"
MODEL = "runtime-fixture-v1"
TAU = 0.5


@dataclass(frozen=True)
class RuntimeKBs:
    """Built bundle folders (read-only) and the answers they were built from."""

    kb: Path  # LLM property KB, sum-tanh, with one forbid override (cut -> umbrella)
    kb_normalized: Path  # the same knowledge built with E_aff form normalized-product
    direct: Path  # direct-LLM baseline bundle
    other_encoder: Path  # ``kb`` with a manifest claiming another text encoder
    w_vp: dict[str, dict[str, float]]
    w_po: dict[str, dict[str, float]]
    objects: list[str]
    verbs: list[str]


def read_answers() -> tuple[dict[str, dict[str, float]], dict[str, dict[str, float]]]:
    """``verb -> prop -> w_vp`` and ``prop -> object -> w_po`` straight from the answer files."""
    w_vp: dict[str, dict[str, float]] = {}
    w_po: dict[str, dict[str, float]] = {}
    for line in (RUNTIME_KB / "vp.jsonl").read_text().splitlines():
        row = json.loads(line)
        w_vp[row["verb"]] = {p["name"]: p["weight"] for p in row["properties"]}
    for line in (RUNTIME_KB / "op.jsonl").read_text().splitlines():
        row = json.loads(line)
        for s in row["scores"]:
            w_po.setdefault(s["property"], {})[row["object"]] = s["weight"]
    return w_vp, w_po


def _names(path: Path) -> list[str]:
    return [ln.strip() for ln in path.read_text().splitlines() if ln.strip()]


@pytest.fixture(scope="session", name="runtime_kbs")
def runtime_kbs_fixture(tmp_path_factory: pytest.TempPathFactory) -> RuntimeKBs:
    from craft_e.compiler.build import BuildConfig, build
    from craft_e.compiler.cache import RecordCache
    from craft_e.compiler.curate import record_answers
    from craft_e.compiler.sources.llm import LLMSource
    from craft_e.paths import CACHE_DIR

    root = tmp_path_factory.mktemp("runtime_kb")
    cache = root / "cache"
    # Records stay in the temporary cache; text embeddings are content-addressed by (encoder, text),
    # so the compiler's own (git-ignored) embedding cache is shared to keep later sessions warm.
    shared_embeddings = CACHE_DIR / "embeddings"
    shared_embeddings.mkdir(parents=True, exist_ok=True)
    cache.mkdir(parents=True)
    (cache / "embeddings").symlink_to(shared_embeddings, target_is_directory=True)
    verbs, objects = _names(RUNTIME_KB / "verbs.txt"), _names(RUNTIME_KB / "objects.txt")
    source = LLMSource(RecordCache(cache), provider=PROVIDER, model=MODEL)
    for prompt, answers in (("verb_properties", "vp.jsonl"), ("object_properties", "op.jsonl"),
                            ("verb_objects", "direct.jsonl")):
        result = record_answers(source, prompt, RUNTIME_KB / answers, verbs, objects,
                                note="runtime test fixture (not knowledge to ship)", version="v1")
        assert not result.skipped, result.skipped

    def make(out: str, **kw: Any) -> Path:
        config = BuildConfig(verbs_file=RUNTIME_KB / "verbs.txt", objects_file=RUNTIME_KB / "objects.txt",
                             out=root / out, name=f"runtime-{out}", provider=PROVIDER, model=MODEL,
                             cache_root=cache, prompt_version="v1", **kw)
        return build(config).out

    kb = make("kb", overrides_file=RUNTIME_KB / "overrides.toml", tau=TAU)
    kb_norm = make("kb-normalized", overrides_file=RUNTIME_KB / "overrides.toml", tau=TAU,
                   energy_form="normalized-product")
    direct = make("direct", mode="direct", tau=0.0)
    other = root / "other-encoder"
    shutil.copytree(kb, other)
    from craft_e.schemas.v1.bundle import Manifest, sealed

    manifest = json.loads((other / "manifest.json").read_text())
    manifest["text_encoder"]["id"] = "clip-vit-b32"  # a validly sealed bundle of another space
    # the tensors record the encoder they were embedded with: relabel them too, so the copy is
    # consistent (only the space differs), and rehash them
    from safetensors import safe_open
    from safetensors.numpy import load_file, save

    emb_path = other / "embeddings.safetensors"
    tensors = load_file(emb_path)
    with safe_open(str(emb_path), framework="numpy") as handle:
        index = json.loads((handle.metadata() or {})["index"])
    index["encoder"] = "clip-vit-b32"
    blob = save(tensors, metadata={"index": json.dumps(index, sort_keys=True)})
    emb_path.write_bytes(blob)
    import hashlib

    manifest["files"]["embeddings.safetensors"] = {"sha256": hashlib.sha256(blob).hexdigest(),
                                                   "bytes": len(blob)}
    resealed = sealed(Manifest.model_validate(manifest))
    (other / "manifest.json").write_text(json.dumps(resealed.model_dump(mode="json"), indent=1))
    w_vp, w_po = read_answers()
    return RuntimeKBs(kb, kb_norm, direct, other, w_vp, w_po, objects, verbs)


@pytest.fixture(scope="session", name="conse")
def conse_fixture() -> Any:
    """The default image encoder (EfficientNet-Lite1 + MiniLM class names), loaded once."""
    from craft_e.runtime.encoders.conse import ConSEImageEncoder

    return ConSEImageEncoder(threads=1)  # one thread: stable timings on busy CI hosts


def shared_image(name: str) -> Path:
    """Path of the shared ImageNet photo of class ``name`` (first one if several)."""
    from craft_e.runtime.evaluation.imagenet import load_dataset

    data = load_dataset()
    return data.images[data.class_images[data.class_index[name]][0]]
