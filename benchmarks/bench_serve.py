"""Benchmark: ``craft serve`` under a bounded load (sustained requests/s, p50/p99 latency, errors).

Starts ``craft serve`` (uvicorn, one process) in a subprocess on 127.0.0.1 with a bundle (default:
the shipped ``artifacts/kb/craft-e-default``), waits for ``GET /healthz``, then drives ``POST
/ground`` from this second process: ``--clients`` threads, each with its own keep-alive httpx
client, for ``--duration`` seconds after a warm-up. Each request carries ``--rois`` ROIs with
random unit embeddings of the bundle's dimension and random grasp scores, for a random KB verb;
request bodies are encoded once up front so the client spends its CPU on HTTP, not JSON.

Client and server share the machine's cores, so the numbers are for the pair; the server's own CPU
time (from ``/proc``) is reported beside them so the server's share can be read off. An optional
single-client phase first (``--baseline-seconds``) gives the unloaded latency.

Run: ``.venv/bin/python benchmarks/bench_serve.py [--clients 8] [--duration 20] [--rois 10]
[--json OUT]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from craft_e.arguments import output_file

REPO = Path(__file__).resolve().parents[1]
DEFAULT_KB = REPO / "artifacts" / "kb" / "craft-e-default"


def free_port() -> int:
    """An ephemeral port that was free a moment ago (the server binds it right after)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def start_server(kb: Path, port: int, image_encoder: str, log: Path) -> subprocess.Popen[bytes]:
    """``craft serve`` in a subprocess (the same CLI a user runs), output to ``log``."""
    code = "from craft_e.runtime.cli.main import app; app(prog_name='craft')"
    cmd = [sys.executable, "-c", code, "serve", "--kb", str(kb), "--host", "127.0.0.1",
           "--port", str(port), "--image-encoder", image_encoder, "--log-level", "warning"]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    with log.open("wb") as handle:
        return subprocess.Popen(cmd, stdout=handle, stderr=subprocess.STDOUT, env=env)


def wait_healthy(base: str, proc: subprocess.Popen[bytes], timeout_s: float, log: Path) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"craft serve exited with {proc.returncode}:\n{log.read_text(errors='replace')}")
        try:
            r = httpx.get(f"{base}/healthz", timeout=1.0)
            if r.status_code == 200:
                health: dict[str, Any] = r.json()
                return health
        except httpx.HTTPError:
            pass
        time.sleep(0.1)
    raise SystemExit(f"craft serve not healthy after {timeout_s} s:\n{log.read_text(errors='replace')}")


def make_bodies(verbs: list[str], dim: int, rois: int, count: int, seed: int) -> list[bytes]:
    """``count`` request bodies: random verb, ``rois`` ROIs with random unit embeddings."""
    rng = np.random.default_rng(seed)
    bodies = []
    for _ in range(count):
        emb = rng.normal(size=(rois, dim)).astype(np.float32)  # [R, d]
        emb /= np.linalg.norm(emb, axis=1, keepdims=True)
        body = {
            "verb": verbs[int(rng.integers(len(verbs)))],
            "rois": [{"box_xywh": [float(40 * i), 10.0, 40.0, 60.0],
                      "grasp_scores": rng.uniform(0.05, 1.0, size=int(rng.integers(1, 6))).round(4).tolist(),
                      "image_embedding": [round(float(v), 6) for v in emb[i]]} for i in range(rois)],
        }
        bodies.append(json.dumps(body).encode())
    return bodies


@dataclass
class ClientStats:
    latencies_s: list[float] = field(default_factory=list)
    statuses: dict[str, int] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)


def client_loop(base: str, bodies: list[bytes], warm_until: float, stop_at: float, offset: int,
                stats: ClientStats) -> None:
    """Post bodies back to back until ``stop_at``; only requests started after warm-up count."""
    headers = {"content-type": "application/json"}
    i = offset
    with httpx.Client(base_url=base, timeout=30.0) as client:
        while True:
            t0 = time.perf_counter()
            if t0 >= stop_at:
                return
            body = bodies[i % len(bodies)]
            i += 1
            try:
                r = client.post("/ground", content=body, headers=headers)
                ok = r.status_code == 200 and r.json().get("ranked") is not None
                key = str(r.status_code)
            except httpx.HTTPError as exc:
                ok, key = False, type(exc).__name__
            t1 = time.perf_counter()
            if t0 < warm_until:
                continue
            stats.latencies_s.append(t1 - t0)
            stats.statuses[key] = stats.statuses.get(key, 0) + 1
            if not ok and len(stats.errors) < 5:
                stats.errors.append(key)


def proc_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of a process (Linux ``/proc``; None elsewhere)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def host_busy_s() -> float | None:
    """CPU seconds all processes on the host have been busy (Linux ``/proc/stat``; None elsewhere)."""
    try:
        fields = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
        idle = fields[3] + (fields[4] if len(fields) > 4 else 0)
        return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def run_phase(base: str, bodies: list[bytes], clients: int, duration_s: float, warmup_s: float,
              server_pid: int) -> dict[str, Any]:
    start = time.perf_counter()
    warm_until, stop_at = start + warmup_s, start + warmup_s + duration_s
    stats = [ClientStats() for _ in range(clients)]
    threads = [threading.Thread(target=client_loop, args=(base, bodies, warm_until, stop_at, k * 7,
                                                          stats[k]), daemon=True)
               for k in range(clients)]
    for t in threads:
        t.start()
    time.sleep(max(0.0, warm_until - time.perf_counter()))
    cpu0, own0, busy0, wall0 = proc_cpu_s(server_pid), time.process_time(), host_busy_s(), time.perf_counter()
    for t in threads:
        t.join()
    cpu1, own1, busy1, wall1 = proc_cpu_s(server_pid), time.process_time(), host_busy_s(), time.perf_counter()
    lat = np.array([x for s in stats for x in s.latencies_s])  # [requests]
    statuses: dict[str, int] = {}
    for s in stats:
        for k, v in s.statuses.items():
            statuses[k] = statuses.get(k, 0) + v
    n = int(lat.size)
    errors = n - statuses.get("200", 0)
    window = wall1 - wall0  # measured window (the last request may end slightly after stop_at)
    pct = (lambda q: round(float(np.percentile(lat, q)) * 1e3, 3)) if n else (lambda q: None)
    server_cpu = None if cpu0 is None or cpu1 is None else cpu1 - cpu0
    other = (None if server_cpu is None or busy0 is None or busy1 is None
             else max(0.0, busy1 - busy0 - server_cpu - (own1 - own0)))
    return {
        "clients": clients, "duration_s": round(window, 3), "requests": n,
        "requests_per_s": round(n / window, 1) if window > 0 else None,
        "latency_ms": {"p50": pct(50), "p90": pct(90), "p99": pct(99),
                       "max": round(float(lat.max()) * 1e3, 3) if n else None,
                       "mean": round(float(lat.mean()) * 1e3, 3) if n else None},
        "errors": errors, "status_counts": statuses,
        "error_examples": sorted({e for s in stats for e in s.errors}),
        "server_cpu_s": None if server_cpu is None else round(server_cpu, 2),
        "server_cpu_ms_per_request": None if server_cpu is None or not n else round(1e3 * server_cpu / n, 3),
        "client_cpu_s": round(own1 - own0, 2),
        # CPU that neither side used: other tenants of the host (a busy neighbour halves throughput)
        "other_cpu_s": None if other is None else round(other, 2),
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kb", type=Path, default=DEFAULT_KB)
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--duration", type=float, default=20.0, help="Measured seconds of the loaded phase.")
    ap.add_argument("--warmup", type=float, default=2.0)
    ap.add_argument("--baseline-seconds", type=float, default=5.0,
                    help="Single-client phase first (0: skip).")
    ap.add_argument("--rois", type=int, default=10)
    ap.add_argument("--bodies", type=int, default=64, help="Distinct precomputed request bodies.")
    ap.add_argument("--image-encoder", default="none", help="Server's --image-encoder (conse | none).")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=output_file, default=None, dest="json_out")
    args = ap.parse_args(argv)
    if args.clients < 1 or args.duration <= 0 or args.rois < 1:
        ap.error("--clients, --duration and --rois must be positive")

    port = free_port()
    base = f"http://127.0.0.1:{port}"
    log = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench_serve.{port}.log"
    t0 = time.perf_counter()
    proc = start_server(args.kb, port, args.image_encoder, log)
    try:
        health = wait_healthy(base, proc, 120.0, log)
        startup_s = time.perf_counter() - t0
        verbs = httpx.get(f"{base}/verbs").json()["verbs"]
        bodies = make_bodies(verbs, int(health["dim"]), args.rois, args.bodies, args.seed)
        phases = []
        if args.baseline_seconds > 0:
            phases.append(run_phase(base, bodies, 1, args.baseline_seconds, 1.0, proc.pid))
        phases.append(run_phase(base, bodies, args.clients, args.duration, args.warmup, proc.pid))
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    result = {
        "benchmark": "craft serve POST /ground",
        "kb": health["kb"], "kb_version": health["version"], "content_sha256": health["content_sha256"],
        "rois_per_request": args.rois, "dim": health["dim"], "body_bytes_mean": int(np.mean([len(b) for b in bodies])),
        "server_startup_s": round(startup_s, 2), "server_exit_code": proc.returncode,
        "image_encoder": args.image_encoder,
        "host": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "phases": phases,
    }
    for p in phases:
        lat = p["latency_ms"]
        print(f"{p['clients']} client(s), {p['duration_s']:.1f} s: {p['requests']} requests, "
              f"{p['requests_per_s']} req/s, p50 {lat['p50']} ms, p99 {lat['p99']} ms, max {lat['max']} ms, "
              f"errors {p['errors']}; server CPU {p['server_cpu_s']} s ({p['server_cpu_ms_per_request']} ms/request), "
              f"client CPU {p['client_cpu_s']} s, other processes {p['other_cpu_s']} s")
    if args.json_out is not None:
        args.json_out.parent.mkdir(parents=True, exist_ok=True)
        args.json_out.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
        print(f"wrote {args.json_out}")
    return result


if __name__ == "__main__":
    main()
