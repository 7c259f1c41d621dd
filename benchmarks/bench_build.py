"""Benchmark: ``craftc build`` from a warm cache, and an incremental rebuild after one verb changes.

The performance promise is that a KB author can rebuild a 100-verb x 400-object bundle from a
warm cache in under 20 s on 2 cores (embeddings included), and that changing one verb re-embeds
only that verb's texts. This script measures exactly that, offline:

1. writes a synthetic vocabulary and synthetic records into a temporary cache under provider
   ``bench-synthetic`` (never ``curated``: these numbers are not knowledge, and the cache is never
   under ``artifacts/``),
2. builds once to warm the embedding cache (not the timed figure),
3. times a second build from the warm cache,
4. changes one verb's record (one property swapped for a new one, whose object scores are then
   written too), times the rebuild and reports how many texts were re-embedded.

Run: ``.venv/bin/python benchmarks/bench_build.py [--verbs 100] [--objects 400] [--json OUT]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import shutil
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from craft_e.arguments import output_file
from craft_e.compiler.build import BuildConfig, BuildResult, build
from craft_e.compiler.cache import RecordCache
from craft_e.compiler.llm_knowledge import K_PROPERTIES, plan_object_calls, verb_call
from craft_e.compiler.sources.llm import LLM_SOURCE, LLMSource, PromptCall
from craft_e.paths import ARTIFACTS_DIR
from craft_e.schemas.v1.payloads import ObjectProperties, VerbProperties
from craft_e.schemas.v1.records import Record

PROVIDER = "bench-synthetic"
MODEL = "synthetic-v1"
NOTE = "synthetic benchmark data from benchmarks/bench_build.py; not knowledge, never ship it"
CHANGED_PROPERTY = "synthetic property new"


@dataclass
class Timing:
    """One timed build, as printed in the table and written to ``--json``."""

    step: str
    seconds: float
    embedded: int
    embeddings_cached: int
    content_sha256: str


def _store(source: LLMSource, call: PromptCall, payload: dict[str, object]) -> None:
    """Store a synthetic answer as the record of its rendered prompt (as a provider would)."""
    request = source.request_for(call)
    source.cache.put(
        Record(
            key=request.key(),
            source=LLM_SOURCE,
            request=request,
            raw_response=json.dumps(payload, sort_keys=True),
            payload=payload,
            note=NOTE,
        )
    )


def write_vocabulary(folder: Path, n_verbs: int, n_objects: int) -> tuple[list[str], list[str]]:
    verbs = [f"synthetic verb {i:03d}" for i in range(n_verbs)]
    objects = [f"synthetic object {i:03d}" for i in range(n_objects)]
    (folder / "verbs.txt").write_text("\n".join(verbs) + "\n", encoding="utf-8")
    (folder / "objects.txt").write_text("\n".join(objects) + "\n", encoding="utf-8")
    return verbs, objects


def _verb_answer(rng: random.Random, verb: str, pool: list[str]) -> dict[str, object]:
    names = rng.sample(pool, K_PROPERTIES)
    return VerbProperties.model_validate(
        {
            "verb": verb,
            "properties": [{"name": n, "weight": round(rng.uniform(0.1, 1.0), 2)} for n in names],
        }
    ).model_dump(mode="json")


def _object_answers(
    source: LLMSource, rng: random.Random, objects: list[str], properties: list[str], density: float
) -> int:
    """Answer every pending object prompt with a sparse random scoring of its named set."""
    _, calls = plan_object_calls(source, objects, properties, version="v1")
    for call in calls:
        named: list[str] = call.variables["properties"]
        chosen = [p for p in named if rng.random() < density] or [rng.choice(named)]
        payload = ObjectProperties.model_validate(
            {
                "object": call.subject,
                "scores": [
                    {"property": p, "weight": round(rng.uniform(0.2, 1.0), 2)} for p in chosen
                ],
            }
        ).model_dump(mode="json")
        _store(source, call, payload)
    return len(calls)


def write_records(
    source: LLMSource, verbs: list[str], objects: list[str], n_properties: int, seed: int
) -> list[str]:
    """Synthetic stage-1 and stage-2 records; returns the property set the verbs use."""
    rng = random.Random(seed)
    pool = [f"synthetic property {j:03d}" for j in range(n_properties)]
    used: set[str] = set()
    for verb in verbs:
        payload = _verb_answer(rng, verb, pool)
        used.update(p["name"] for p in payload["properties"])  # type: ignore[attr-defined]
        _store(source, verb_call(verb, version="v1"), payload)
    properties = sorted(used)
    _object_answers(source, rng, objects, properties, density=0.05)
    return properties


def change_one_verb(
    source: LLMSource, verb: str, objects: list[str], properties: list[str], seed: int
) -> None:
    """Swap one of ``verb``'s properties for a new one and score the new one for every object.

    Only the new property is uncovered by existing object records, so stage 2 plans one small
    request per object (as a live provider would be asked), answered here synthetically.
    """
    record = source.lookup(verb_call(verb, version="v1"))
    assert record is not None, f"no record for {verb}"
    payload = VerbProperties.model_validate(record.payload).model_dump(mode="json")
    payload["properties"][0] = {"name": CHANGED_PROPERTY, "weight": 0.9}
    _store(source, verb_call(verb, version="v1"), VerbProperties.model_validate(payload).model_dump(mode="json"))
    wanted = sorted({*properties, CHANGED_PROPERTY})
    _object_answers(source, random.Random(seed + 1), objects, wanted, density=0.3)


def timed_build(step: str, config: BuildConfig) -> tuple[Timing, BuildResult]:
    started = time.perf_counter()
    result = build(config)
    seconds = time.perf_counter() - started
    return Timing(
        step,
        round(seconds, 3),
        result.embedding_misses,
        result.embedding_hits,
        result.manifest.content_sha256,
    ), result


def run(
    n_verbs: int, n_objects: int, n_properties: int, workdir: Path, seed: int
) -> dict[str, object]:
    cache_root = workdir / "cache"
    source = LLMSource(RecordCache(cache_root), provider=PROVIDER, model=MODEL)
    started = time.perf_counter()
    verbs, objects = write_vocabulary(workdir, n_verbs, n_objects)
    properties = write_records(source, verbs, objects, n_properties, seed)
    setup_s = time.perf_counter() - started
    config = BuildConfig(
        verbs_file=workdir / "verbs.txt",
        objects_file=workdir / "objects.txt",
        out=workdir / "bundle",
        name="bench-synthetic",
        provider=PROVIDER,
        model=MODEL,
        cache_root=cache_root,
        prompt_version="v1",  # synthetic answers in the v1 payload shape (no definitions/roles)
    )
    warmup, _ = timed_build("warm-up build (cold embedding cache, not the target)", config)
    warm, result = timed_build("build from a warm cache", config)
    change_one_verb(source, verbs[0], objects, properties, seed)
    incremental, _ = timed_build(f"rebuild after changing {verbs[0]!r}", config)
    return {
        "verbs": n_verbs,
        "objects": n_objects,
        "properties": len(result.manifest.properties),
        "records": sum(1 for _ in (cache_root / LLM_SOURCE).glob("*.json")),
        "setup_s": round(setup_s, 3),
        "timings": [asdict(t) for t in (warmup, warm, incremental)],
        "target_s": 20.0,
        "warm_build_meets_target": warm.seconds < 20.0,
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "machine": platform.machine(),
    }


def render(report: dict[str, object]) -> str:
    timings = report["timings"]
    assert isinstance(timings, list)
    lines = [
        f"craftc build benchmark: {report['verbs']} verbs x {report['objects']} objects, "
        f"{report['properties']} properties, {report['records']} records "
        f"({report['cpus']} CPUs, synthetic data set up in {report['setup_s']} s)",
        "",
        "| step | seconds | texts embedded | texts cached |",
        "|---|---:|---:|---:|",
    ]
    lines += [
        f"| {t['step']} | {t['seconds']:.2f} | {t['embedded']} | {t['embeddings_cached']} |"
        for t in timings
    ]
    verdict = "meets" if report["warm_build_meets_target"] else "MISSES"
    lines += [
        "",
        f"warm build {timings[1]['seconds']:.2f} s {verdict} the {report['target_s']} s target",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--verbs", type=int, default=100)
    parser.add_argument("--objects", type=int, default=400)
    parser.add_argument("--properties", type=int, default=300, help="size of the property pool")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=output_file, default=None, help="also write the figures here")
    parser.add_argument(
        "--workdir",
        type=Path,
        default=None,
        help="scratch folder (default: a new temporary folder, removed after)",
    )
    args = parser.parse_args(argv)
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="craft-bench-"))
    checkout_artifacts = Path(__file__).resolve().parents[1] / "artifacts"  # wherever it runs from
    for artifacts in {ARTIFACTS_DIR.resolve(), checkout_artifacts}:
        if workdir.resolve().is_relative_to(artifacts):
            parser.error(f"--workdir {workdir} is inside {artifacts}: synthetic records never go there")
    marker = workdir / ".craft-bench-workdir"
    if args.workdir is not None and workdir.exists() and any(workdir.iterdir()) and not marker.exists():
        parser.error(f"--workdir {workdir} holds files this benchmark did not write; give an empty or "
                     "new folder (the benchmark overwrites its verbs.txt, objects.txt and cache there)")
    workdir.mkdir(parents=True, exist_ok=True)
    marker.write_text("scratch folder of benchmarks/bench_build.py\n", encoding="utf-8")
    try:
        report = run(args.verbs, args.objects, args.properties, workdir, args.seed)
    finally:
        if args.workdir is None:
            shutil.rmtree(workdir, ignore_errors=True)
    print(render(report))
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return 0 if report["warm_build_meets_target"] else 1


if __name__ == "__main__":
    sys.exit(main())
