"""Benchmark: how long a robot waits for one bundle: ``load_bundle`` (verified) and ``Grounder()``.

Both run ``--repeats`` times after one warm-up load (page cache warm, imports done: the state a
robot restarts into); the medians are printed and, with ``--json``, written. The bundle is any
bundle folder, by default the shipped ``craft-e-default`` (81 verbs x 628 objects); a 10,000-object
one comes from ``benchmarks/bench_scale.py --workdir DIR`` (``DIR/1000x10000/bundle``).

To compare two versions of the code on the same machine, run it after
``git checkout <commit> -- runtime schemas`` and again after ``git checkout HEAD -- runtime schemas``
(the bundle format is the same, so one bundle serves both).

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_load.py [--bundle DIR] [--repeats 7] [--json OUT]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

from craft_e.arguments import output_file, positive_int
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.kb.bundle import BundleError, load_bundle

DEFAULT_BUNDLE = Path(__file__).resolve().parents[1] / "artifacts" / "kb" / "craft-e-default"


def measure(bundle: Path, repeats: int) -> dict[str, float | int | str]:
    """Median seconds of ``load_bundle`` and of ``Grounder(bundle)`` over ``repeats`` runs."""
    load_bundle(bundle)
    loads: list[float] = []
    grounders: list[float] = []
    for _ in range(repeats):
        started = time.perf_counter()
        loaded = load_bundle(bundle)
        loads.append(time.perf_counter() - started)
        started = time.perf_counter()
        Grounder(loaded)
        grounders.append(time.perf_counter() - started)
    m = loaded.manifest
    return {"bundle": str(bundle), "verbs": len(m.verbs), "objects": len(m.objects), "repeats": repeats,
            "load_s": round(statistics.median(loads), 4), "grounder_s": round(statistics.median(grounders), 4),
            "machine": f"{platform.machine()}, Python {platform.python_version()}"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bundle", type=Path, default=DEFAULT_BUNDLE, help="a bundle folder")
    parser.add_argument("--repeats", type=positive_int, default=7, help="timed loads (and grounders)")
    parser.add_argument("--json", type=output_file, default=None, help="write the result here")
    args = parser.parse_args(argv)
    try:
        result = measure(args.bundle, args.repeats)
    except BundleError as exc:
        print(f"bench_load: {exc}", file=sys.stderr)
        return 2
    print(f"{result['verbs']} verbs x {result['objects']} objects: load_bundle {result['load_s']} s, "
          f"Grounder() {result['grounder_s']} s (medians of {args.repeats})")
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
