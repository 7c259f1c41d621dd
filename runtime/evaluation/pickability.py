"""Pickability: every testbed asset alone on the table, picked by the robot's whole pipeline.

Why: the testbed's Grasp Rate mixes three causes. ``craft eval sim`` splits a wrong choice into
knowledge and perception; this isolates the third, the pick, per asset and over every asset of the
catalogue (74), not only the targets of the dev labels. It needs no verb and no label, so it says
before any labelled run which objects the robot cannot pick up however well it chose them.

Each asset is placed alone ``layouts`` times (seeded poses, as ``craft eval sim`` places a scene)
and run through ``sim.pipeline.run_episode`` exactly as ``craft eval sim`` runs it: predicted ROIs,
the grasp network, the finger and IK checks, refinements, the antipodal fallback, relocation, the
wrist look and physics. The one method grounds with E_grasp alone (the CRAFT-E bundle at
beta = gamma = 0), so with one object the choice is the region with the best usable grasp. An
episode's outcome is ``craft eval sim``'s: ``no_grasp`` (no grasp on the object passed the checks),
``wrong_object`` (the segmenter split the object and the chosen piece is not it, IoU < 0.5),
``no_target_roi`` (no region covers it), or the pick's own result in physics.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .methods import MethodSpec, build_grounders, default_methods, load_methods
from .sim_eval import (
    EpisodeSpec,
    asset_footprint,
    default_encoder,
    episode_rng,
    placeable,
    plain_name,
    run_one_episode,
    text_space,
    worker_context,
)

if TYPE_CHECKING:
    from ..grounding.settings import GroundingSettings
    from ..sim.env import EnvConfig
    from ..sim.pipeline import PipelineConfig

#: the one method: the CRAFT-E bundle with no knowledge and no alignment term
METHOD = "grasp-only"
#: what an episode's ``verb`` is called (no verb is grounded: beta = 0)
VERB = "pick"

ProgressFn = Callable[[int, int, dict[str, Any]], None]


class UnknownAssetError(ValueError):
    """An asked-for asset is not in the testbed's catalogue."""


def pickability_method(kb: Path | None = None, kb_dir: Path | None = None) -> MethodSpec:
    """The CRAFT-E bundle scored by E_grasp alone (beta = gamma = 0)."""
    kwargs: dict[str, Any] = {} if kb_dir is None else {"kb_dir": kb_dir}
    craft_e = next(m for m in default_methods(kb, **kwargs) if m.name == "CRAFT-E")
    return dataclasses.replace(craft_e, name=METHOD, description="E_grasp alone (CRAFT-E bundle, beta = gamma = 0)",
                               beta=0.0, gamma=0.0)


def check_assets(assets: Sequence[str]) -> list[str]:
    """``assets`` as asset ids, in the order given (none: every asset). Each entry is an asset id
    or a plain name of the catalogue ("marker": every marker asset), as labels files take them."""
    from ..sim.assets import object_catalog

    catalog = object_catalog()
    if not assets:
        return sorted(catalog)
    out: list[str] = []
    unknown: list[str] = []
    for entry in assets:
        if entry in catalog:
            out.append(entry)
            continue
        named = sorted(a for a, o in catalog.items() if o.name == plain_name(entry))
        if named:
            out.extend(named)
        else:
            unknown.append(entry)
    if unknown:
        import difflib

        known = sorted({*catalog, *(o.name for o in catalog.values())})
        hints = [f"{u!r}: did you mean {' or '.join(map(repr, close))}?" for u in unknown
                 if (close := difflib.get_close_matches(plain_name(u), known, n=2))]
        raise UnknownAssetError(f"unknown asset(s) {', '.join(map(repr, unknown))}: give asset ids or plain names of "
                                f"the sim catalogue (runtime/sim/objects.json), e.g. {', '.join(sorted(catalog)[:3])}"
                                + ("; " + "; ".join(hints) if hints else ""))
    return list(dict.fromkeys(out))


def pickability_specs(assets: Sequence[str], *, layouts: int = 3, seed: int = 0,
                      env_config: EnvConfig | None = None) -> list[EpisodeSpec]:
    """``layouts`` single-object scenes per asset; the scene seed is drawn from (seed, asset,
    layout) as ``craft eval sim`` draws a pair's, so an asset's scenes do not depend on which
    other assets are asked for."""
    from ..sim.env import EnvConfig
    from ..sim.placement import PlacementError
    from ..sim.scene import SceneSpec

    if layouts < 1:
        raise ValueError(f"layouts must be >= 1, got {layouts}")
    env_cfg = env_config or EnvConfig()
    specs: list[EpisodeSpec] = []
    for asset in assets:
        for layout in range(layouts):
            scene_seed = int(episode_rng(seed, VERB, asset, layout).integers(2**31 - 1))
            if not placeable((asset,), scene_seed, env_cfg.layout.placement, env_cfg.physics.fine_collision):
                raise PlacementError(f"asset {asset!r} layout {layout}: cannot be placed on the table")
            specs.append(EpisodeSpec(VERB, asset, layout, SceneSpec(VERB, asset, (), scene_seed), 1))
    return specs


@dataclass
class PickabilityReport:
    """Every episode's record (``sim_eval.episode_record``) and the run's settings."""

    episodes: list[dict[str, Any]]
    config: dict[str, Any]
    notes: list[str] = field(default_factory=list)

    def outcome(self, record: dict[str, Any]) -> str:
        return str(record["methods"][METHOD]["failure"])

    def why(self, asset: str, limit: int = 100) -> str:
        """The first failed episode of ``asset``: its layout, and the pick's detail or, without a
        pick, the grasp checks' (``three_d_detail``), cut to ``limit`` characters."""
        for record in self.episodes:
            if record["target"] == asset and self.outcome(record) != "success":
                m = record["methods"][METHOD]
                text = " ".join((m["pick_detail"] or record["three_d_detail"] or self.outcome(record)).split())
                text = text if len(text) <= limit else text[: limit - 1] + "…"
                return f"{record['layout']}: {text}".replace("|", "/")
        return ""

    def per_asset(self) -> dict[str, Counter[str]]:
        """Outcome counts per asset, in run order."""
        out: dict[str, Counter[str]] = {}
        for record in self.episodes:
            out.setdefault(record["target"], Counter())[self.outcome(record)] += 1
        return out

    def to_dict(self) -> dict[str, Any]:
        per = self.per_asset()
        n = max(len(self.episodes), 1)
        return {
            "benchmark": "pickability (each asset alone; the robot's whole pipeline; E_grasp alone)",
            "config": self.config,
            "success_rate": round(sum(self.outcome(r) == "success" for r in self.episodes) / n, 6),
            "outcomes": dict(sorted(Counter(self.outcome(r) for r in self.episodes).items())),
            "assets": {a: {"episodes": sum(c.values()), "success": c["success"], "outcomes": dict(sorted(c.items()))}
                       for a, c in per.items()},
            "episodes": self.episodes,
            "notes": self.notes,
        }

    def to_markdown(self) -> str:
        c = self.config
        per = self.per_asset()
        n = len(self.episodes)
        wins = sum(self.outcome(r) == "success" for r in self.episodes)
        totals = Counter(self.outcome(r) for r in self.episodes)
        lines = [
            f"### Pickability: {c['assets']} assets alone × {c['layouts']} layouts = {n} episodes "
            f"(seed {c['seed']}, grasp `{c['pipeline']['grasp']}`, ROIs `{c['pipeline']['rois']}`, "
            f"gripper `{c['gripper']}`, widest section it closes on {100 * c['max_span_m']:.1f} cm)",
            "",
            "Each asset alone on the table, picked by the pipeline `craft eval sim` runs, choosing by "
            "E_grasp alone: what the pick itself loses, with no knowledge or recognition involved.",
            "",
            f"Picked: **{wins}/{n}** episodes ({100 * wins / max(n, 1):.1f} %); "
            + ", ".join(f"{k} {v}" for k, v in sorted(totals.items(), key=lambda kv: (-kv[1], kv[0]))) + ".",
            "",
        ]
        always = [a for a, k in per.items() if k["success"] == sum(k.values())]
        rest = sorted((a for a in per if a not in always), key=lambda a: (per[a]["success"], a))
        if rest:
            lines += ["| asset | footprint (cm) | picked | other outcomes | why, first such episode |",
                      "|---|---|---:|---|---|"]
            for a in rest:
                k = per[a]
                others = ", ".join(f"{o} {v}" for o, v in sorted(k.items()) if o != "success")
                lines.append(f"| {a} | {c['footprints_cm'][a]} | {k['success']}/{sum(k.values())} | {others} | "
                             f"{self.why(a)} |")
            lines.append("")
        lines.append(f"Picked in every layout ({len(always)}): " + (", ".join(sorted(always)) or "none") + ".")
        lines.append("")
        lines.append("Footprint: the asset's base box as loaded upright (before it settles), edges in cm, "
                     "longest first (a settled object may lie on its side); the finger check accepts sections up to the "
                     "widest in the title.")
        return "\n".join(lines) + "\n"


def evaluate_pickability(
    assets: Sequence[str] = (),
    *,
    config: PipelineConfig | None = None,
    layouts: int = 3,
    seed: int = 0,
    env_config: EnvConfig | None = None,
    settings: GroundingSettings | None = None,
    method: MethodSpec | None = None,
    progress: ProgressFn | None = None,
    jobs: int = 1,
) -> PickabilityReport:
    """Run every asset's episodes (``assets``: all when empty); ``jobs`` > 1 runs them in worker
    processes with the same records as ``jobs=1`` (``evaluation.parallel``)."""
    from ..grounding.settings import GroundingSettings
    from ..sim.env import EnvConfig
    from ..sim.pipeline import PipelineConfig, sim_vocabulary
    from .parallel import ordered_map

    cfg = config or PipelineConfig()
    env_cfg = env_config or EnvConfig()
    chosen = check_assets(assets)
    specs = pickability_specs(chosen, layouts=layouts, seed=seed, env_config=env_cfg)
    # the cavity cue, the hubness correction, the senses and ConSE's temperature off: grounding with
    # E_grasp alone never reads p(o | r), and with them the records' diagnostic hypothesis would
    # differ from the published runs' (made before them)
    settings = settings or GroundingSettings(cavity_cue=False, hubness=False, sense_weight=0.0, conse_temperature=1.0)
    spec_m = method or pickability_method()
    runnable, _ = load_methods([spec_m], text_space(None))  # raises NoMethodToRunError if it cannot run
    enc = default_encoder(cfg.torch_threads, sense_weight=settings.class_senses, temperature=settings.conse_temperature)
    grounders = build_grounders(runnable, settings, sim_vocabulary())
    build = partial(worker_context, [m for m, _ in runnable], cfg.torch_threads, settings, None)
    records: list[dict[str, Any]] = []
    for record in ordered_map(partial(run_one_episode, cfg, env_cfg, None), specs, jobs=jobs, build=build,
                              context=(grounders, enc)):
        records.append(record)
        if progress is not None:
            progress(len(records), len(specs), record)
    footprints = {a: " × ".join(f"{200 * h:.1f}" for h in sorted(
        asset_footprint(a, env_cfg.physics.fine_collision).half_size, reverse=True)) for a in chosen}
    config_out = {
        "assets": len(chosen), "layouts": layouts, "seed": seed, "episodes": len(specs),
        "method": {"name": spec_m.name, "bundle": str(spec_m.bundle), "beta": spec_m.beta, "gamma": spec_m.gamma},
        "pipeline": cfg.to_dict(), "gripper": env_cfg.gripper.hand, "max_span_m": round(cfg.fingers.max_span, 6),
        "fine_collision": env_cfg.physics.fine_collision, "wrist_look": cfg.pick.wrist.enabled,
        "relocate": cfg.pick.clearance.relocate, "table_clearance_m": cfg.pick.table_clearance,
        "clearance_margin_m": cfg.pick.clearance.margin, "gentle_below_m": cfg.pick.gentle_below,
        "carry_margin_m": cfg.pick.carry_margin if cfg.pick.carry_check else None,
        "image_encoder": enc.id, "footprints_cm": footprints,
    }
    return PickabilityReport(records, config_out)
