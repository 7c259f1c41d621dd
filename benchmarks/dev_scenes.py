"""What the "readings" benchmarks share (``bench_classifier_readings.py``, ``bench_scene_readings.py``):
the sim-dev episodes perceived once as ``craft eval sim`` does, and their per-seed table.

Each benchmark reads the same crops in other ways and scores every reading by in-scene
recognition (top-1 / top-5 over the regions of a vocabulary object) and by CRAFT-E's and
direct-LLM's Detect. Imported by those scripts (their folder is on ``sys.path`` when they run);
not a program itself.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from craft_e.runtime.evaluation.sim_eval import load_sim_labels, make_episode_specs
from craft_e.runtime.perception.roi import ROI
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.perceive import grounding_rois, perceive
from craft_e.runtime.sim.pipeline import PipelineConfig

Probs = npt.NDArray[np.float64]
METHODS = ("CRAFT-E", "direct-LLM")


@dataclasses.dataclass
class Episode:
    """What one perceived episode leaves for the readings."""

    verb: str
    rois: list[ROI]
    target_roi: int | None
    names: list[str | None]  # each ROI's majority object's name (scoring only)
    probs: dict[str, Probs]  # what the benchmark's ``extra`` recorded (classifier reading -> [N, 1000])


def perceive_seed(labels: Path, layouts: int, seed: int, cfg: PipelineConfig, encoder: Any,
                  extra: Callable[[list[ROI]], dict[str, Probs]] | None = None) -> list[Episode]:
    """Every episode of one layout seed, perceived once as ``craft eval sim`` does (``perceive``,
    the defaults) through ``encoder``; ``extra(rois)``, called right after each perception, keeps
    what a benchmark needs beyond the ROIs."""
    specs = make_episode_specs(load_sim_labels(labels), layouts=layouts, seed=seed)
    episodes: list[Episode] = []
    with SimEnv() as env:
        for n, spec in enumerate(specs):
            env.reset(spec.scene)
            perception = perceive(env, encoder, cfg, cavity=True)
            rois = grounding_rois(perception)
            names_by_body = {o.body_id: o.name for o in env.scene.objects}
            names = [names_by_body.get(r.body) if r.body is not None else None for r in perception.rois]
            probs = extra(rois) if extra is not None and rois else {}
            episodes.append(Episode(spec.verb, rois, perception.target_roi, names, probs))
            print(f"\rseed {seed}: {n + 1}/{len(specs)} episodes", end="", flush=True)
    print()
    return episodes


def rank_of(p_row: Probs, vocab: list[str], name: str) -> int:
    """How many names ``p(o | r)`` puts strictly ahead of the region's true name (0: top-1)."""
    return int((p_row > p_row[vocab.index(name)]).sum())


def seed_table(title: str, rows: list[dict[str, Any]], seeds: list[int]) -> str:
    """The markdown table of every reading: per seed, top-1 / top-5 and each method's Detect."""
    lines = [f"{title}\n",
             "Per seed: in-scene top-1 / top-5 % over the regions of a vocabulary object; CRAFT-E and "
             "direct-LLM Detect (episodes whose choice is the target's ROI).\n",
             "| reading | " + " | ".join(f"seed {s}: top-1 / top-5 | CRAFT-E | direct-LLM" for s in seeds) + " |",
             "|---" + "|---:|---:|---:" * len(seeds) + "|"]
    for row in rows:
        cells = [f"{r['top1']:.1f} / {r['top5']:.1f} | {r['detect']['CRAFT-E']}/{r['episodes']} | "
                 f"{r['detect']['direct-LLM']}/{r['episodes']}" for r in row["seeds"]]
        lines.append(f"| {row['reading']} | " + " | ".join(cells) + " |")
    regions = ", ".join(f"seed {r['seed']}: {r['regions']}" for r in rows[0]["seeds"])
    return "\n".join(lines) + f"\n\nRegions scored: {regions}.\n"


def publish(table: str, payload: dict[str, Any], markdown: Path | None, json_path: Path | None) -> None:
    """Print the table; write it to ``markdown`` and ``payload`` to ``json_path`` where given."""
    print(table)
    if markdown is not None:
        markdown.write_text(table, encoding="utf-8")
    if json_path is not None:
        json_path.write_text(json.dumps(payload, indent=1) + "\n", encoding="utf-8")
