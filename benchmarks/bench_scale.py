"""Benchmark: how ``craftc build`` and the runtime grow, 100x400 -> 300x3,000 -> 1,000x10,000.

For each size (verbs x objects) this script

1. writes a synthetic vocabulary and synthetic stage-1/stage-2 (prompt v2) records into a
   temporary cache under provider ``bench-synthetic`` (never ``curated``, never under
   ``artifacts/``: these numbers measure code paths, not knowledge). Each verb names 10 properties
   from a pool of ``min(3 V, 300)``; each object has about 15 of them (w_po in [0.2, 1]);
2. **cold build**: ``craftc build`` with an empty embedding cache, so every text is embedded
   with MiniLM (``--fake-embeddings``: hash-seeded random unit vectors instead, labelled so in
   the output; the build then measures everything but the encoder);
3. **warm rebuild**: one verb's record changes (one property swapped for a new one, which every
   object is then asked about in one small record each, as a live provider would be), and the
   bundle is rebuilt from the warm caches;
4. ``load_bundle`` (verified: every file's sha256, the manifest hash, content checks), and
   ``Grounder.ground`` for 10 ROIs with random unit image embeddings over the whole object
   vocabulary (median over repeated calls, cached verb plans, ``OPENBLAS_NUM_THREADS=1``).

Each step runs in its own child process so ``peak_mb`` (``ru_maxrss``) is that step's alone:
the cold build's peak includes the MiniLM encoder (torch) unless ``--fake-embeddings``.

``--rdflib`` also times, at the first size, one warm build whose ``graph.ttl`` is written by
rdflib's Turtle serializer (the writer before issue 14 item 3) against one with the canonical
writer, in the same process, and reports the ratio.

Run: ``.venv/bin/python benchmarks/bench_scale.py [--sizes 100x400,300x3000,1000x10000]
[--fake-embeddings] [--rdflib] [--json OUT] [--plot OUT.png] [--markdown OUT.md]``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import random
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from craft_e.arguments import output_file, positive_int

PROVIDER = "bench-synthetic"
MODEL = "synthetic-v1"
NOTE = "synthetic benchmark data from benchmarks/bench_scale.py; not knowledge, never ship it"
PROPERTIES_PER_VERB = 10
PROPERTIES_PER_OBJECT = 15
CHANGED_PROPERTY = "prop new"
DEFAULT_SIZES = "100x400,300x3000,1000x10000"
ROIS = 10
TARGETS = {"ground_ms": 5.0, "load_s": 1.0, "rebuild_share": 0.10}


# ---------------------------------------------------------------------------------------------
# synthetic records (child process)


#: Stage 2 asks every object about the whole property set, so records grow as objects x
#: properties (1.2 GB of records at 1,000 x 10,000 with 1,000 properties); the pool is capped.
MAX_PROPERTIES = 300


def _pool_size(n_verbs: int) -> int:
    return min(3 * n_verbs, MAX_PROPERTIES)


def _bulk_store(cache_root: Path, records: list[Any]) -> None:
    """Write records as ``RecordCache.put`` would (same bytes, same ``SHA256SUMS``), but the
    index once for all of them: ``put`` rewrites the index per record, O(N^2) at 10k objects.
    The cache is temporary, so files are not fsynced one by one."""
    from craft_e.compiler.cache import INDEX_FILE, read_index, record_bytes, sha256_hex

    folder = cache_root / "llm"
    folder.mkdir(parents=True, exist_ok=True)
    entries = read_index(folder / INDEX_FILE)
    for record in records:
        data = record_bytes(record)
        name = f"{record.key}.json"
        (folder / name).write_bytes(data)
        entries[name] = sha256_hex(data)
    (folder / INDEX_FILE).write_text(
        "".join(f"{d}  {n}\n" for n, d in sorted(entries.items())), encoding="utf-8"
    )


def _record(source: Any, call: Any, payload: dict[str, Any]) -> Any:
    from craft_e.compiler.sources.llm import LLM_SOURCE
    from craft_e.schemas.v1.records import Record

    request = source.request_for(call)
    return Record(
        key=request.key(),
        source=LLM_SOURCE,
        request=request,
        raw_response=json.dumps(payload, sort_keys=True),
        payload=payload,
        note=NOTE,
    )


def _verb_payload(verb: str, names: list[str], rng: random.Random) -> dict[str, Any]:
    from craft_e.schemas.v1.payloads import VerbPropertiesV2

    return VerbPropertiesV2.model_validate(
        {
            "verb": verb,
            "properties": [
                {
                    "name": n,
                    "definition": f"defines {n}",
                    "role": "required" if i == 0 else "helpful",
                    "weight": round(rng.uniform(0.1, 1.0), 2),
                }
                for i, n in enumerate(names)
            ],
        }
    ).model_dump(mode="json")


def _object_records(
    source: Any, objects: list[str], properties: list[str], definitions: dict[str, str],
    per_object: float, rng: random.Random,
) -> list[Any]:
    from craft_e.compiler.llm_knowledge import object_call
    from craft_e.schemas.v1.payloads import ObjectProperties

    density = min(1.0, per_object / max(len(properties), 1))
    out = []
    for obj in objects:
        call = object_call(obj, properties, definitions=definitions)
        named: list[str] = call.variables["properties"]
        chosen = [p for p in named if rng.random() < density] or [rng.choice(named)]
        payload = ObjectProperties.model_validate(
            {
                "object": obj,
                "scores": [
                    {"property": p, "weight": round(rng.uniform(0.2, 1.0), 2)} for p in chosen
                ],
            }
        ).model_dump(mode="json")
        out.append(_record(source, call, payload))
    return out


def write_kb(workdir: Path, n_verbs: int, n_objects: int, seed: int) -> dict[str, Any]:
    """Vocabularies + records for one size; returns what the later steps need."""
    from craft_e.compiler.cache import RecordCache
    from craft_e.compiler.llm_knowledge import verb_call
    from craft_e.compiler.sources.llm import LLMSource

    rng = random.Random(seed)
    verbs = [f"synthetic verb {i:04d}" for i in range(n_verbs)]
    objects = [f"synthetic object {i:05d}" for i in range(n_objects)]
    (workdir / "verbs.txt").write_text("\n".join(verbs) + "\n", encoding="utf-8")
    (workdir / "objects.txt").write_text("\n".join(objects) + "\n", encoding="utf-8")
    pool = [f"prop {j:04d}" for j in range(_pool_size(n_verbs))]
    source = LLMSource(RecordCache(workdir / "cache"), provider=PROVIDER, model=MODEL)
    records = []
    used: dict[str, str] = {}
    for verb in verbs:
        payload = _verb_payload(verb, rng.sample(pool, PROPERTIES_PER_VERB), rng)
        for p in payload["properties"]:
            used.setdefault(p["name"], p["definition"])
        records.append(_record(source, verb_call(verb), payload))
    properties = sorted(used)
    records += _object_records(
        source, objects, properties, used, PROPERTIES_PER_OBJECT, rng
    )
    _bulk_store(workdir / "cache", records)
    return {"verbs": verbs, "objects": objects, "properties": properties, "definitions": used}


def change_one_verb(workdir: Path, kb: dict[str, Any], seed: int) -> None:
    """Swap verb 0's first property for a new one; answer the new property for every object
    in one small stage-2 record each (what ``plan_object_calls`` asks a live provider)."""
    from craft_e.compiler.cache import RecordCache
    from craft_e.compiler.llm_knowledge import verb_call
    from craft_e.compiler.sources.llm import LLMSource
    from craft_e.schemas.v1.payloads import VerbPropertiesV2

    source = LLMSource(RecordCache(workdir / "cache"), provider=PROVIDER, model=MODEL)
    verb = kb["verbs"][0]
    record = source.lookup(verb_call(verb))
    assert record is not None, f"no record for {verb}"
    props = [dict(p) for p in record.payload["properties"]]
    props[0] = {**props[0], "name": CHANGED_PROPERTY, "definition": "a new synthetic property"}
    rng = random.Random(seed + 1)
    changed = VerbPropertiesV2.model_validate({"verb": verb, "properties": props})
    records = [_record(source, verb_call(verb), changed.model_dump(mode="json"))]
    defs = {**kb["definitions"], CHANGED_PROPERTY: "a new synthetic property"}
    records += _object_records(source, kb["objects"], [CHANGED_PROPERTY], defs, 0.1, rng)
    _bulk_store(workdir / "cache", records)


# ---------------------------------------------------------------------------------------------
# child steps


class FakeEncoder:
    """Hash-seeded random unit vectors: stands in for MiniLM under ``--fake-embeddings``."""

    dim = 384

    def embed(self, texts: list[str]) -> Any:
        import numpy as np

        out = np.empty((len(texts), self.dim), dtype=np.float32)
        for i, text in enumerate(texts):
            seed = int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "little")
            vec = np.random.default_rng(seed).normal(size=self.dim).astype(np.float32)
            out[i] = vec / np.linalg.norm(vec)
        return out


def _config(workdir: Path) -> Any:
    from craft_e.compiler.build import BuildConfig

    return BuildConfig(
        verbs_file=workdir / "verbs.txt",
        objects_file=workdir / "objects.txt",
        out=workdir / "bundle",
        name="bench-synthetic",
        provider=PROVIDER,
        model=MODEL,
        cache_root=workdir / "cache",
        energy_form="normalized-product",
    )


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _timed_build(workdir: Path) -> tuple[float, Any]:
    from craft_e.compiler.build import build

    started, cpu = time.perf_counter(), time.process_time()
    result = build(_config(workdir))
    result.cpu_s = time.process_time() - cpu
    return time.perf_counter() - started, result


def step_setup(workdir: Path, n_verbs: int, n_objects: int, seed: int) -> dict[str, Any]:
    started = time.perf_counter()
    kb = write_kb(workdir, n_verbs, n_objects, seed)
    (workdir / "kb.json").write_text(json.dumps(kb), encoding="utf-8")
    return {"setup_s": time.perf_counter() - started, "properties": len(kb["properties"])}


def step_build(workdir: Path, fake: bool) -> dict[str, Any]:
    if fake:
        import craft_e.compiler.embed as embed

        embed.load_text_encoder = lambda _id: FakeEncoder()  # type: ignore[assignment]
    seconds, result = _timed_build(workdir)
    return {
        "seconds": seconds,
        "cpu_s": result.cpu_s,
        "peak_mb": _peak_mb(),
        "embedded": result.embedding_misses,
        "embeddings_cached": result.embedding_hits,
        "content_sha256": result.manifest.content_sha256,
        "counts": result.report.counts,
    }


def step_change(workdir: Path, seed: int) -> dict[str, Any]:
    kb = json.loads((workdir / "kb.json").read_text(encoding="utf-8"))
    change_one_verb(workdir, kb, seed)
    return {}


def step_profile(workdir: Path, out: Path) -> dict[str, Any]:
    """cProfile of one warm build, written to ``out`` (pstats)."""
    import cProfile

    profiler = cProfile.Profile()
    profiler.enable()
    seconds, _ = _timed_build(workdir)
    profiler.disable()
    profiler.dump_stats(str(out))
    return {"seconds": seconds}


def step_rdflib(workdir: Path) -> dict[str, Any]:
    """One warm build with rdflib's Turtle serializer, then one with the canonical writer."""
    import craft_e.compiler.build as build_module

    canonical = build_module.graph_turtle
    build_module.graph_turtle = rdflib_turtle
    try:
        old_s, _ = _timed_build(workdir)
    finally:
        build_module.graph_turtle = canonical
    new_s, _ = _timed_build(workdir)
    return {"rdflib_s": old_s, "canonical_s": new_s}


def rdflib_turtle(graph: Any, kb_name: str) -> bytes:
    """``graph.ttl`` as rdflib wrote it before issue 14 item 3 (``git show 62a2fcc~3:compiler/rdf.py``),
    with the triples the canonical writer added since (comments, roles) so both write one graph."""
    from urllib.parse import quote

    from rdflib import RDF, RDFS, Graph, Literal, Namespace, URIRef
    from rdflib.namespace import XSD

    craft = Namespace("https://craft-e.dev/ns#")
    base = Namespace(f"https://craft-e.dev/kb/{kb_name}/")

    def uri(node_id: str) -> URIRef:
        kind, name = node_id.split(":", 1)
        return URIRef(f"{base}{kind}/{quote(name.replace(' ', '_'), safe='')}")

    rdf = Graph()
    rdf.bind("craft", craft)
    rdf.bind("kb", base)
    kinds = {"verb": craft.Verb, "property": craft.Property, "object": craft.Object}
    for node in sorted(graph.nodes):
        data = graph.nodes[node]
        rdf.add((uri(node), RDF.type, kinds[data["kind"]]))
        rdf.add((uri(node), RDFS.label, Literal(data["name"])))
        for key in ("gloss", "definition"):
            if data.get(key):
                rdf.add((uri(node), RDFS.comment, Literal(data[key])))
    for u, v in sorted(graph.edges):
        data = graph.edges[u, v]
        su, sv = uri(u), uri(v)
        rdf.add((su, craft.hasProperty if u.startswith("verb:") else craft.propertyOf, sv))
        link = URIRef(f"{base}link/{hashlib.sha256(f'{u}|{v}'.encode()).hexdigest()[:16]}")
        rdf.add((link, RDF.type, craft.Link))
        rdf.add((link, craft.source, su))
        rdf.add((link, craft.target, sv))
        rdf.add((link, craft.weight, Literal(f"{data['weight']:.6f}", datatype=XSD.decimal)))
        rdf.add((link, craft.relation, Literal(data["relation"])))
        if data.get("role"):
            rdf.add((link, craft.role, Literal(data["role"])))
        for prov in data["provenance"]:
            rdf.add((link, craft.provenance, Literal(prov)))
    text: str = rdf.serialize(format="turtle")
    return text.encode()


def step_runtime(workdir: Path, repeats: int, seed: int) -> dict[str, Any]:
    import numpy as np

    from craft_e.runtime.grounding.grounder import ROI, Grounder
    from craft_e.runtime.kb.bundle import load_bundle

    path = workdir / "bundle"
    bundle_bytes = sum(p.stat().st_size for p in path.iterdir() if p.is_file())
    load_bundle(path)  # page cache warm, imports done: the steady state a robot restarts into
    loads = []
    for _ in range(3):
        started = time.perf_counter()
        bundle = load_bundle(path)
        loads.append(time.perf_counter() - started)
    started = time.perf_counter()
    grounder = Grounder(bundle)
    grounder_s = time.perf_counter() - started
    rng = np.random.default_rng(seed)
    verbs = bundle.manifest.verbs[:20]
    rois = []
    for _ in range(ROIS):
        x = rng.normal(size=grounder.dim).astype(np.float32)
        rois.append(ROI((0, 0, 10, 10), [float(rng.uniform(0.2, 1.0))], [],
                        x / np.linalg.norm(x)))
    for verb in verbs:  # plan every verb once (cached by the grounder)
        grounder.ground(verb, rois)
    times = []
    for i in range(repeats):
        started = time.perf_counter()
        grounder.ground(verbs[i % len(verbs)], rois)
        times.append(time.perf_counter() - started)
    files = {p.name: round(p.stat().st_size / 1e6, 2) for p in sorted(path.iterdir())}
    nonzero = float(np.count_nonzero(bundle.energy)) / max(bundle.energy.size, 1)
    return {
        "load_s": statistics.median(loads),
        "grounder_s": grounder_s,
        "ground_ms": statistics.median(times) * 1000,
        "ground_p90_ms": sorted(times)[int(0.9 * len(times))] * 1000,
        "bundle_mb": bundle_bytes / 1e6,
        "files_mb": files,
        "energy_nonzero_share": nonzero,
        "peak_mb": _peak_mb(),
    }


STEPS = {"setup", "build", "change", "runtime", "rdflib", "profile"}


def child_main(args: argparse.Namespace) -> int:
    workdir = Path(args.workdir)
    if args.step == "setup":
        out = step_setup(workdir, args.n_verbs, args.n_objects, args.seed)
    elif args.step == "build":
        out = step_build(workdir, args.fake_embeddings)
    elif args.step == "change":
        out = step_change(workdir, args.seed)
    elif args.step == "runtime":
        out = step_runtime(workdir, args.repeats, args.seed)
    elif args.step == "rdflib":
        out = step_rdflib(workdir)
    else:
        out = step_profile(workdir, Path(args.profile_out))
    print("RESULT " + json.dumps(out))
    return 0


# ---------------------------------------------------------------------------------------------
# parent: one child per step


def _run_child(step: str, workdir: Path, args: argparse.Namespace, **extra: Any) -> dict[str, Any]:
    cmd = [sys.executable, __file__, "--step", step, "--workdir", str(workdir),
           "--seed", str(args.seed), "--repeats", str(args.repeats)]
    if args.fake_embeddings:
        cmd.append("--fake-embeddings")
    for key, value in extra.items():
        cmd += [f"--{key.replace('_', '-')}", str(value)]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1",
           "TRANSFORMERS_OFFLINE": "1"}
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if proc.returncode != 0:
        sys.stderr.write(proc.stdout[-4000:] + proc.stderr[-4000:])
        raise SystemExit(f"step {step} failed ({proc.returncode}) in {workdir}")
    line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")][-1]
    result: dict[str, Any] = json.loads(line[len("RESULT "):])
    return result


def measure(n_verbs: int, n_objects: int, root: Path, args: argparse.Namespace) -> dict[str, Any]:
    workdir = root / f"{n_verbs}x{n_objects}"
    workdir.mkdir(parents=True, exist_ok=True)
    log = lambda msg: print(f"[{n_verbs}x{n_objects}] {msg}", file=sys.stderr, flush=True)  # noqa: E731
    setup = _run_child("setup", workdir, args, n_verbs=n_verbs, n_objects=n_objects)
    log(f"records written in {setup['setup_s']:.1f} s ({setup['properties']} properties)")
    cold = _run_child("build", workdir, args)
    log(f"cold build {cold['seconds']:.2f} s, {cold['embedded']} texts embedded")
    warm = _run_child("build", workdir, args)
    log(f"warm build (nothing changed) {warm['seconds']:.2f} s")
    rdflib: dict[str, Any] = {}
    if args.rdflib and (n_verbs, n_objects) == args.sizes[0]:
        rdflib = _run_child("rdflib", workdir, args)
        log(f"warm build with rdflib Turtle {rdflib['rdflib_s']:.2f} s, canonical writer "
            f"{rdflib['canonical_s']:.2f} s")
    _run_child("change", workdir, args)
    rebuild = _run_child("build", workdir, args)
    log(f"rebuild after changing one verb {rebuild['seconds']:.2f} s "
        f"({rebuild['embedded']} texts embedded)")
    if args.profile:
        out = Path(args.profile) / f"build-{n_verbs}x{n_objects}.pstats"
        out.parent.mkdir(parents=True, exist_ok=True)
        _run_child("profile", workdir, args, profile_out=out.resolve())
        log(f"profile of a warm build: {out}")
    run = _run_child("runtime", workdir, args)
    log(f"load {run['load_s']:.3f} s, ground {run['ground_ms']:.3f} ms, {run['bundle_mb']:.1f} MB")
    counts = cold["counts"]
    return {
        "verbs": n_verbs,
        "objects": n_objects,
        "build_s": round(cold["seconds"], 3),
        "peak_mb": round(cold["peak_mb"], 1),
        "bundle_mb": round(run["bundle_mb"], 2),
        "load_s": round(run["load_s"], 4),
        "ground_ms": round(run["ground_ms"], 4),
        "properties": counts["properties"],
        "property_object_edges": counts["property_object_edges"],
        "embedded": cold["embedded"],
        "embeddings": "fake (hash-seeded random)" if args.fake_embeddings else "MiniLM",
        "build_cpu_s": round(cold["cpu_s"], 3),
        "warm_build_s": round(warm["seconds"], 3),
        "warm_build_cpu_s": round(warm["cpu_s"], 3),
        "rebuild_cpu_s": round(rebuild["cpu_s"], 3),
        "energy_nonzero_share": round(run["energy_nonzero_share"], 4),
        "warm_build_peak_mb": round(warm["peak_mb"], 1),
        "rebuild_s": round(rebuild["seconds"], 3),
        "rebuild_share": round(rebuild["seconds"] / cold["seconds"], 4),
        "rebuild_embedded": rebuild["embedded"],
        "grounder_s": round(run["grounder_s"], 4),
        "ground_p90_ms": round(run["ground_p90_ms"], 4),
        "load_peak_mb": round(run["peak_mb"], 1),
        "files_mb": run["files_mb"],
        "setup_s": round(setup["setup_s"], 2),
        **({"rdflib_warm_build_s": round(rdflib["rdflib_s"], 3),
            "canonical_warm_build_s": round(rdflib["canonical_s"], 3)} if rdflib else {}),
    }


def render(rows: list[dict[str, Any]]) -> str:
    fake = any(r["embeddings"] != "MiniLM" for r in rows)
    lines = [
        f"craftc build / runtime growth ({os.cpu_count()} CPUs, load average "
        f"{os.getloadavg()[0]:.1f}, Python {platform.python_version()}; embeddings: "
        f"{rows[0]['embeddings']}{' -- NOT the MiniLM encoder, build_s excludes embedding time' if fake else ''})",
        "",
        "| verbs × objects | properties | P→O edges | cold build s (CPU s) | peak MB "
        "| warm rebuild s (CPU s), one verb changed | rebuild / cold | bundle MB "
        "| E_aff cells ≠ 0 | load_bundle s | Grounder() s | ground() 10 ROIs ms |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['verbs']:,} × {r['objects']:,} | {r['properties']:,} | "
            f"{r['property_object_edges']:,} | {r['build_s']:.2f} ({r['build_cpu_s']:.1f}) | "
            f"{r['peak_mb']:.0f} | {r['rebuild_s']:.2f} ({r['rebuild_cpu_s']:.1f}) | "
            f"{100 * r['rebuild_share']:.1f} % | {r['bundle_mb']:.1f} | "
            f"{100 * r['energy_nonzero_share']:.0f} % | {r['load_s']:.3f} | "
            f"{r['grounder_s']:.3f} | {r['ground_ms']:.3f} |"
        )
    for r in rows:
        if "rdflib_warm_build_s" in r:
            ratio = r["rdflib_warm_build_s"] / r["canonical_warm_build_s"]
            lines += ["", f"warm build at {r['verbs']} × {r['objects']}: rdflib Turtle "
                      f"{r['rdflib_warm_build_s']:.2f} s, canonical writer "
                      f"{r['canonical_warm_build_s']:.2f} s ({ratio:.1f}× faster)"]
    big = rows[-1]
    lines += ["", f"targets at {big['verbs']:,} × {big['objects']:,}: ground() "
              f"{big['ground_ms']:.2f} ms (≤ {TARGETS['ground_ms']:g}), load "
              f"{big['load_s']:.2f} s (≤ {TARGETS['load_s']:g}), rebuild "
              f"{100 * big['rebuild_share']:.1f} % of cold (≤ {100 * TARGETS['rebuild_share']:g} %)"]
    return "\n".join(lines)


def plot(rows: list[dict[str, Any]], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = [r["verbs"] * r["objects"] for r in rows]
    labels = [f"{r['verbs']}×{r['objects']}" for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    series = [
        (axes[0], [("cold build", "build_s"), ("warm rebuild, one verb changed", "rebuild_s"),
                   ("load_bundle", "load_s")], "seconds"),
        (axes[1], [("ground(), 10 ROIs", "ground_ms")], "milliseconds"),
        (axes[2], [("bundle size", "bundle_mb"), ("peak RSS, cold build", "peak_mb")], "MB"),
    ]
    for ax, items, unit in series:
        for label, key in items:
            ax.plot(cells, [r[key] for r in rows], marker="o", label=label)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(cells, labels, fontsize=8)
        ax.minorticks_off()
        ax.set_xlabel("verbs × objects")
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    emb = rows[0]["embeddings"]
    fig.suptitle(f"CRAFT-E growth (synthetic KBs, embeddings: {emb}, {os.cpu_count()} CPUs)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def _sizes(text: str) -> list[tuple[int, int]]:
    """--sizes: comma-separated VERBSxOBJECTS, each count >= 1, checked at parse time."""
    sizes = []
    for part in text.split(","):
        counts = part.strip().lower().split("x")
        if len(counts) != 2:
            raise argparse.ArgumentTypeError(f"{part!r} is not VERBSxOBJECTS (e.g. 100x400)")
        sizes.append((positive_int(counts[0]), positive_int(counts[1])))
    return sizes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--sizes", type=_sizes, default=DEFAULT_SIZES,
                        help="comma-separated VERBSxOBJECTS (default %(default)s)")
    parser.add_argument("--fake-embeddings", action="store_true",
                        help="hash-seeded random unit vectors instead of MiniLM (labelled)")
    parser.add_argument("--rdflib", action="store_true",
                        help="also time a warm build with rdflib's Turtle serializer (first size)")
    parser.add_argument("--profile", default=None, help="folder for cProfile stats of warm builds")
    parser.add_argument("--repeats", type=positive_int, default=300, help="ground() calls per size")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=output_file, default=None, help="write the rows here")
    parser.add_argument("--plot", type=output_file, default=None, help="write a PNG plot here")
    parser.add_argument("--markdown", type=output_file, default=None, help="write the table here")
    parser.add_argument("--workdir", default=None,
                        help="scratch folder (default: a new temporary folder, removed after)")
    parser.add_argument("--step", choices=sorted(STEPS),
                        help="run one step alone, in this process, on the size folder --workdir holds "
                             "(e.g. DIR/1000x10000 of a run with --workdir DIR): how a run calls its "
                             "children, and how two versions of the code are compared on one KB "
                             "(build: a warm build and its content hash; runtime: load, Grounder(), ground())")
    parser.add_argument("--n-verbs", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--n-objects", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--profile-out", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.step:
        return child_main(args)
    from craft_e.paths import ARTIFACTS_DIR

    root = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="craft-scale-"))
    if root.resolve().is_relative_to(ARTIFACTS_DIR.resolve()):
        parser.error(f"--workdir {root} is inside {ARTIFACTS_DIR}: synthetic records never go there")
    root.mkdir(parents=True, exist_ok=True)
    rows = []
    try:
        for n_verbs, n_objects in args.sizes:
            rows.append(measure(n_verbs, n_objects, root, args))
    finally:
        if args.workdir is None:
            shutil.rmtree(root, ignore_errors=True)
    table = render(rows)
    print(table)
    if args.markdown is not None:
        args.markdown.write_text(table + "\n", encoding="utf-8")
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=2) + "\n", encoding="utf-8")
    if args.plot is not None:
        plot(rows, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
