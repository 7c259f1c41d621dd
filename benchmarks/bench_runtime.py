"""Benchmark: the runtime's hot paths on a robot-sized KB.

Promises measured here (2-core CPU, no GPU):

* ``Grounder.ground`` for 10 ROIs with precomputed image embeddings and a 400-object vocabulary:
  median < 1 ms (everything bundle-dependent is precomputed in the constructor);
* image encoder (ConSE: EfficientNet-Lite1 (Lite0 before 2026-12-04) + class-name embeddings) per ROI crop and per batch
  of 10 crops;
* ``load_bundle`` (verify every file's sha256 + the manifest hash, parse, load arrays).

The KB is synthetic (100 verbs x 400 objects x 300 properties, random unit embeddings, 10
properties per verb, ~20 objects per property), written straight from the v1 schemas into a
temporary folder: these numbers measure code paths, not knowledge. Crops are cut from the shared
ImageNet photos.

Run: ``.venv/bin/python benchmarks/bench_runtime.py [--threads N] [--repeats 500] [--json OUT]``.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from safetensors.numpy import save as save_safetensors

from craft_e.arguments import output_file, positive_int
from craft_e.runtime.encoders.text import MINILM_DIM, MINILM_ID, MINILM_SHA256
from craft_e.runtime.grounding.energies import affordance_energy_matrix
from craft_e.runtime.grounding.grounder import ROI, Grounder
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.schemas.v1.bundle import (
    UNSEALED,
    BundleReport,
    Coverage,
    EnergyInfo,
    FileDigest,
    Manifest,
    SourceInfo,
    TextEncoderInfo,
    sealed,
)


def _unit(rng: np.random.Generator, n: int) -> np.ndarray[Any, np.dtype[np.float32]]:
    x = rng.normal(size=(n, MINILM_DIM)).astype(np.float32)
    out: np.ndarray[Any, np.dtype[np.float32]] = x / np.linalg.norm(x, axis=1, keepdims=True)
    return out


def write_synthetic_bundle(out: Path, verbs: int = 100, objects: int = 400, properties: int = 300,
                           seed: int = 0) -> Path:
    """A valid v1 bundle of random knowledge (provider ``bench-synthetic``; never ship it)."""
    rng = np.random.default_rng(seed)
    v_names = [f"verb {i}" for i in range(verbs)]
    o_names = [f"object {j}" for j in range(objects)]
    p_names = [f"property {k}" for k in range(properties)]
    w_vp = np.zeros((verbs, properties), np.float32)  # [V, P]
    w_po = np.zeros((properties, objects), np.float32)  # [P, O]
    for i in range(verbs):
        w_vp[i, rng.choice(properties, 10, replace=False)] = rng.uniform(0.1, 1.0, 10).round(2)
    for k in range(properties):
        w_po[k, rng.choice(objects, 20, replace=False)] = rng.uniform(0.3, 1.0, 20).round(2)
    energy = affordance_energy_matrix(w_vp, w_po, tau=0.5)  # [V, O]
    rec = hashlib.sha256(b"bench-synthetic").hexdigest()
    nodes = ([{"id": f"verb:{v}", "kind": "verb", "name": v} for v in v_names]
             + [{"id": f"prop:{p}", "kind": "property", "name": p} for p in p_names]
             + [{"id": f"obj:{o}", "kind": "object", "name": o} for o in o_names])
    edges = [{"source": f"verb:{v_names[i]}", "target": f"prop:{p_names[k]}", "weight": float(w_vp[i, k]),
              "relation": "llm", "provenance": [rec]} for i, k in zip(*np.nonzero(w_vp), strict=True)]
    edges += [{"source": f"prop:{p_names[k]}", "target": f"obj:{o_names[j]}", "weight": float(w_po[k, j]),
               "relation": "llm", "provenance": [rec]} for k, j in zip(*np.nonzero(w_po), strict=True)]
    graph = {"directed": True, "multigraph": False, "nodes": nodes, "edges": edges}
    buf = io.BytesIO()
    np.save(buf, energy, allow_pickle=False)
    tensors = {"verb": _unit(rng, verbs), "verb_query": _unit(rng, verbs), "object": _unit(rng, objects),
               "property": _unit(rng, properties)}
    report = BundleReport(kb_name="bench-synthetic", counts={"verbs": verbs, "objects": objects}, pass_counts={},
                          drops=[], coverage=Coverage(verbs_with_fewer_than_k_properties={},
                                                      objects_without_properties=[],
                                                      objects_unreachable_from_any_verb=[],
                                                      verbs_reaching_no_object=[]))
    files = {
        "graph.json": json.dumps(graph).encode(),
        "graph.ttl": b"# synthetic benchmark bundle: no RDF\n",
        "embeddings.safetensors": save_safetensors(tensors),
        "affordance_energy.npy": buf.getvalue(),
        "report.json": report.model_dump_json().encode(),
    }
    manifest = sealed(Manifest(
        kb_name="bench-synthetic", kb_version="0.0.1", content_sha256=UNSEALED,
        files={n: FileDigest(sha256=hashlib.sha256(b).hexdigest(), bytes=len(b)) for n, b in files.items()},
        sources=[SourceInfo(kind="llm", provider="bench-synthetic", model="synthetic", records=0)],
        text_encoder=TextEncoderInfo(id=MINILM_ID, weights_sha256=MINILM_SHA256, dim=MINILM_DIM,
                                     verb_template="something to {verb}"),
        energy=EnergyInfo(form="sum-tanh", tau=0.5), verbs=v_names, objects=o_names, properties=p_names,
    ))
    out.mkdir(parents=True, exist_ok=True)
    for name, blob in files.items():
        (out / name).write_bytes(blob)
    (out / "manifest.json").write_text(manifest.model_dump_json(indent=1))
    return out


def _median_ms(fn: Any, repeats: int, warmup: int = 3) -> tuple[float, float]:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    times.sort()
    return 1000 * statistics.median(times), 1000 * times[int(0.9 * (len(times) - 1))]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=None, help="torch threads for the image encoder")
    parser.add_argument("--repeats", type=positive_int, default=500)
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("--skip-encoder", action="store_true", help="only the KB-side figures")
    args = parser.parse_args()
    rows: list[dict[str, Any]] = []

    def report(what: str, median_ms: float, p90_ms: float | None = None, note: str = "") -> None:
        rows.append({"what": what, "median_ms": round(median_ms, 4),
                     "p90_ms": None if p90_ms is None else round(p90_ms, 4), "note": note})
        p90 = "" if p90_ms is None else f"  p90 {p90_ms:9.3f} ms"
        print(f"{what:<52} median {median_ms:9.3f} ms{p90}  {note}", flush=True)

    with tempfile.TemporaryDirectory(prefix="bench-runtime-") as tmp:
        folder = write_synthetic_bundle(Path(tmp) / "kb")
        size = sum(p.stat().st_size for p in folder.iterdir()) / 1e6
        med, p90 = _median_ms(lambda: load_bundle(folder), max(5, args.repeats // 50), warmup=1)
        report("load_bundle (100 verbs x 400 objects)", med, p90, f"{size:.1f} MB on disk")
        kb = load_bundle(folder)
        t = time.perf_counter()
        grounder = Grounder(kb)
        report("Grounder(bundle) constructor", 1000 * (time.perf_counter() - t))
        t = time.perf_counter()
        Grounder(kb, GroundingSettings(energy_form="normalized-product"))
        report("Grounder(bundle, normalized-product) constructor", 1000 * (time.perf_counter() - t),
               note="recomputes E_aff from graph edges")
        rng = np.random.default_rng(1)
        emb = _unit(rng, 10)
        rois = [ROI((0, 0, 10, 10), list(rng.uniform(0.2, 1.0, 5)), image_embedding=e) for e in emb]
        med, p90 = _median_ms(lambda: grounder.ground("verb 7", rois), args.repeats)
        report("ground(): 10 ROIs, 400-object vocabulary", med, p90, "target < 1 ms")
        argmax = Grounder(kb, GroundingSettings(aff_mode="argmax"))
        med, p90 = _median_ms(lambda: argmax.ground("verb 7", rois), args.repeats)
        report("ground(): same, aff_mode=argmax", med, p90)
        many = [ROI((0, 0, 10, 10), [0.9], image_embedding=e) for e in _unit(rng, 100)]
        med, p90 = _median_ms(lambda: grounder.ground("verb 7", many), max(20, args.repeats // 5))
        report("ground(): 100 ROIs", med, p90)

    if not args.skip_encoder:
        from craft_e.runtime.encoders.conse import ConSEImageEncoder
        from craft_e.runtime.encoders.image import crop_box, load_image
        from craft_e.runtime.evaluation.imagenet import load_dataset

        t = time.perf_counter()
        enc = ConSEImageEncoder(threads=args.threads)
        report("ConSE encoder load (weights sha256 + cached class names)", 1000 * (time.perf_counter() - t))
        data = load_dataset()
        crops = []
        for path in data.images[:10]:
            img = load_image(str(path))
            h, w = img.shape[:2]
            crops.append(crop_box(img, (w * 0.2, h * 0.2, w * 0.6, h * 0.6)))
        enc.embed_images(crops[:2])  # warm-up
        med, p90 = _median_ms(lambda: enc.embed_images(crops[:1]), 10, warmup=1)
        report("ConSE embed_images: 1 crop", med, p90)
        med, p90 = _median_ms(lambda: enc.embed_images(crops, batch_size=10), 5, warmup=1)
        report("ConSE embed_images: batch of 10 crops", med, p90, f"{med / 10:.1f} ms per crop")

    import torch

    info = {"python": sys.version.split()[0], "machine": platform.machine(), "cpus": os.cpu_count(),
            "torch_threads": args.threads or torch.get_num_threads(),
            "load_avg": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}
    print(json.dumps(info))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"host": info, "results": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
