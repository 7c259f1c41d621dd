"""What the frame benchmarks share (``bench_frame_noise.py``, ``bench_frame_views.py``): their
options, CRAFT-E set up as ``craft perceive`` runs it on the sim-dev scenes, and how a run is
published (the table printed, the Markdown and the JSON written with the command and its timing).

Imported by those scripts (their folder is on ``sys.path`` when they run); not a program itself.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from craft_e.arguments import output_file, positive_int
from craft_e.paths import KB_DIR, SIM_DEV_LABELS


def percent(k: int, n: int) -> str:
    """``k/n (share %)`` for a table cell, ``-`` for no scenes."""
    return f"{k}/{n} ({100 * k / n:.1f})" if n else "-"


def options(description: str, *, seed: bool = False) -> argparse.ArgumentParser:
    """``--labels``, ``--scenes``, ``--json``, ``--markdown`` (and ``--seed`` for random draws);
    the script parses them first thing, so ``--help`` and typos stop it before any work."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--labels", type=Path, default=SIM_DEV_LABELS)
    parser.add_argument("--scenes", type=positive_int, default=None, help="the first N pairs (default: all)")
    if seed:
        parser.add_argument("--seed", type=int, default=0, help="seeds every noise and hole draw")
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("--markdown", type=output_file, default=None)
    return parser


@dataclass
class FrameRun:
    """The sim-dev scenes (one layout per pair), CRAFT-E as ``craft perceive`` grounds a frame
    (``craft-e-default``, the sim vocabulary, the robot's encoder at 1 thread, the default
    ``PipelineConfig`` with a frame's segmentation, ``frame.FRAME_SEGMENT``), and the run's
    start, for its timing."""

    args: argparse.Namespace
    specs: list[Any] = field(init=False)
    encoder: Any = field(init=False)
    grounder: Any = field(init=False)
    config: Any = field(init=False)
    load: tuple[float, float, float] = field(init=False)
    start: float = field(init=False)

    def __post_init__(self) -> None:
        from craft_e.runtime.evaluation.sim_eval import (
            default_encoder,
            load_sim_labels,
            make_episode_specs,
        )
        from craft_e.runtime.frame import FRAME_SEGMENT
        from craft_e.runtime.grounding.grounder import Grounder
        from craft_e.runtime.grounding.settings import GroundingSettings
        from craft_e.runtime.kb.bundle import load_bundle
        from craft_e.runtime.sim.pipeline import PipelineConfig, sim_vocabulary

        self.load = os.getloadavg()
        self.start = time.perf_counter()
        self.specs = make_episode_specs(load_sim_labels(self.args.labels), layouts=1, max_pairs=self.args.scenes)
        self.encoder = default_encoder(1)
        self.grounder = Grounder(load_bundle(KB_DIR / "craft-e-default"), GroundingSettings(vocabulary=sim_vocabulary()))
        self.config = PipelineConfig(segment=FRAME_SEGMENT)

    @property
    def command(self) -> str:
        return shlex.join([".venv/bin/python", *sys.argv])

    def progress(self, done: int) -> None:
        print(f"\r{done}/{len(self.specs)} scenes", end="", file=sys.stderr, flush=True)

    def publish(self, text: str, payload: dict[str, Any]) -> None:
        """Print the table and the run's timing; write ``--markdown`` (the table) and ``--json``
        (``payload`` after the command, the scene count, the labels, the KB and the timing)."""
        print(file=sys.stderr)
        seconds = time.perf_counter() - self.start
        load_after = os.getloadavg()
        print(text)
        print(f"{seconds:.0f} s, load average {self.load[0]:.2f} before / {load_after[0]:.2f} after, "
              f"{os.cpu_count()} CPUs")
        if self.args.markdown is not None:
            self.args.markdown.write_text(text, encoding="utf-8")
        if self.args.json is not None:
            head = {"command": self.command, "scenes": len(self.specs), "labels": str(self.args.labels),
                    "kb": "craft-e-default"}
            timing = {"seconds": round(seconds, 1), "load_average": [round(self.load[0], 2), round(load_after[0], 2)],
                      "cpus": os.cpu_count()}
            self.args.json.write_text(json.dumps({**head, **payload, **timing}, indent=1) + "\n", encoding="utf-8")
