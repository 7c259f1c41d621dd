"""``craft sim demo``: one headless testbed episode with a figure, a GIF and the explanation."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from . import episodes as ep
from .common import BetaOpt, GammaOpt, checked_output_folder

if TYPE_CHECKING:
    from ..evaluation.sim_eval import EpisodeSpec, LabelPair, SimLabels
    from ..sim.env import EnvConfig


def demo(
    verb: Annotated[str, typer.Option(help="The request, e.g. cut.")],
    seed: Annotated[int, typer.Option(min=0, help="Layout seed (also picks the target among the verb's pairs); "
                                           "with --episode, the --seed that `craft eval sim` ran with.")] = 0,
    kb: Annotated[Path | None, typer.Option(help="Bundle (default artifacts/kb/craft-e-default).")] = None,
    out: Annotated[Path, typer.Option(help="Folder for the PNG, GIF and episode JSON.",
                                      callback=checked_output_folder)] = Path("out/sim_demo"),
    labels: Annotated[Path | None, typer.Option(help="Labels CSV the target and distractors come from "
                                                     "(default: artifacts/labels/sim_dev_labels.csv).")] = None,
    target: Annotated[str | None, typer.Option(help="Target asset id or plain name among the verb's pairs.")] = None,
    episode: Annotated[str | None, typer.Option(
        help="Replay one episode of `craft eval sim` by its id, verb/object/layout as in the results JSON, "
             "e.g. cut/knife/1: the same scene, here with a figure and a GIF "
             "(add --seed N for a run with --seed N).")] = None,
    grasp: Annotated[str, typer.Option(help="grconvnet | ggcnn | ggcnn2 | antipodal | oracle.")] = "grconvnet",
    rois: Annotated[str, typer.Option(help="predicted | oracle.")] = "predicted",
    gif_every: Annotated[int, typer.Option(min=1, help="Simulation steps between GIF frames.")] = 24,
    threads: Annotated[int, typer.Option(min=1, help="Torch threads.")] = 1,
    gripper: ep.GripperOpt = "panda",
    wrist_look: ep.WristLookOpt = True,
    refine_grasps: ep.RefineGraspsOpt = True,
    grasp_fallback: ep.GraspFallbackOpt = True,
    fallback_thin_centres: ep.FallbackThinCentresOpt = 32,
    clearance: ep.ClearanceOpt = False,
    relocate: ep.RelocateOpt = True,
    fine_collision: ep.FineCollisionOpt = True,
    in_view: ep.InViewOpt = True,
    landing_check: ep.LandingCheckOpt = True,
    retries: ep.RetriesOpt = 0,
    active_look: ep.ActiveLookOpt = False,
    size_cue: ep.SizeCueOpt = None,
    colour_cue: ep.ColourCueOpt = None,
    lookalikes: ep.LookalikesOpt = None,
    cavity_cue: ep.CavityCueOpt = None,
    hubness: ep.HubnessOpt = None,
    sense_weight: ep.SenseWeightOpt = None,
    conse_temperature: ep.ConseTemperatureOpt = None,
    beta: BetaOpt = None,
    gamma: GammaOpt = None,
) -> None:
    """Run one episode: capture, ROIs, grasps, grounding, pick; write the paper's figure and a GIF."""
    from ...paths import KB_DIR, SIM_DEV_LABELS
    from ..evaluation.methods import MethodSpec, build_grounders, energy_weights
    from ..evaluation.sim_eval import (
        SimLabels,
        default_encoder,
        episode_record,
        make_episode_specs,
    )
    from ..frame import FRAME_SUFFIXES, save_frame
    from ..grounding.grounder import normalize_verb_name
    from ..grounding.settings import GroundingSettings
    from ..grounding.size_cue import CueUnavailableError
    from ..kb.bundle import BundleError, load_bundle
    from ..sim.env import SimEnv
    from ..sim.figures import FrameRecorder, describe, plot_episode
    from ..sim.pipeline import run_episode, sim_vocabulary
    from ..sim.retry import RetryConfig
    from .common import err, fail
    from .common import out as console

    env_config, config = ep.pick_pipeline(grasp, rois, threads, gripper, wrist_look, clearance, fine_collision,
                                          landing_check, relocate, refine_grasps, grasp_fallback,
                                          active_look=active_look, in_view=in_view,
                                          fallback_thin_centres=fallback_thin_centres)
    all_labels = ep.check_labels(labels or SIM_DEV_LABELS)
    name = normalize_verb_name(verb)
    pairs = [p for p in all_labels.pairs if p.verb == name]
    if not pairs:
        fail(f"verb {name!r} has no pairs in {all_labels.path}; it has: {', '.join(all_labels.verbs)}")
    if episode is not None:
        if target is not None:
            fail(f"--episode {episode} names a fixed scene: drop --target")
        spec = _evaluation_episode(episode, name, pairs, all_labels, env_config, seed)
        stem = episode.replace("/", "_").replace(" ", "_") + (f"_seed{seed}" if seed else "")
    else:
        if target is not None:
            pairs = [p for p in pairs if target in (p.object, *p.assets)]
            if not pairs:
                fail(f"{target!r} does not afford {name!r} in {all_labels.path}")
        pair = pairs[seed % len(pairs)]
        chosen_labels = SimLabels(all_labels.path, (pair,), all_labels.affording)
        spec = make_episode_specs(chosen_labels, layouts=1, seed=seed, env_config=env_config)[0]
        stem = f"{name.replace(' ', '_')}_{seed}"
    # every file the demo writes, checked before the episode runs: a folder in the way of one
    # (not ours) ended the demo in a traceback after the figure and GIF were written
    outputs = [out / f"{stem}{suffix}" for suffix in (".png", ".gif", ".json", *FRAME_SUFFIXES)]
    in_the_way = [p for p in outputs if p.exists() and not p.is_file()]
    if in_the_way:
        fail(f"{in_the_way[0]}: is a folder (or not a file), and the demo writes a file there; "
             "move it, or give another --out")
    bundle_path = kb or KB_DIR / "craft-e-default"
    try:
        bundle = load_bundle(bundle_path)
    except BundleError as exc:
        fail(str(exc))
    method = bundle.manifest.kb_name
    encoder = default_encoder(threads, sense_weight=sense_weight, temperature=conse_temperature)
    try:
        weight_b, weight_g = energy_weights(beta, gamma)
        spec_m = MethodSpec(method, "demo", bundle_path, beta=weight_b, gamma=weight_g)
        grounders = build_grounders([(spec_m, bundle)], GroundingSettings(size_cue=size_cue, colour_cue=colour_cue,
                                                                        lookalikes=lookalikes,
                                                                        cavity_cue=cavity_cue, hubness=hubness,
                                  sense_weight=sense_weight, conse_temperature=conse_temperature),
                                    sim_vocabulary())
    except CueUnavailableError as exc:
        fail(str(exc))
    if cavity_cue and not grounders[method].cavity_cue_active:
        err.print(f"note: --cavity-cue: the bundle {bundle_path} does not define 'is concave' for every object "
                  "of the sim vocabulary; grounding without the cue", highlight=False, markup=False)
    err.print(f"scene: {spec.scene.verb!r}, target {spec.scene.target} among "
              f"{', '.join(spec.scene.distractors)} (layout seed {spec.scene.seed})", highlight=False, markup=False)
    with SimEnv(env_config) as env:
        recorder = FrameRecorder(env.client, every=gif_every)
        env.step_hook = recorder

        def start_recording(_: str) -> None:
            recorder.active = True
            recorder.snapshot()

        result = run_episode(env, spec.scene, grounders, encoder, config, before_pick=start_recording,
                             retry=RetryConfig(retries=retries))
        if not recorder.frames:  # nothing was executed: a still of the scene
            recorder.snapshot()
    out.mkdir(parents=True, exist_ok=True)
    png = plot_episode(result, method, out / f"{stem}.png", gripper=gripper)
    gif = recorder.save(out / f"{stem}.gif")
    record = episode_record(spec, result)
    (out / f"{stem}.json").write_text(json.dumps(record, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    frame = save_frame(out, stem, result.perception.obs)
    console.print(describe(result, method, gripper=gripper), highlight=False, markup=False, soft_wrap=True)
    err.print(f"wrote {png}, {gif} ({len(recorder.frames)} frames), {out / (stem + '.json')}", highlight=False, markup=False)
    err.print(f"the camera's frame, for `craft perceive`: {', '.join(str(p) for p in frame)}", highlight=False,
              markup=False)


def _evaluation_episode(
    episode: str, verb: str, pairs: Sequence[LabelPair], labels: SimLabels, env_config: EnvConfig,
    seed: int = 0,
) -> EpisodeSpec:
    """The scene ``craft eval sim --seed <seed>`` (the same labels) runs as ``episode``
    (``verb/object/layout``): a pair's layouts are drawn from the pair and the seed alone, so
    building that one pair's layouts reproduces it without the rest of the file."""
    from ..evaluation.sim_eval import SimLabels, make_episode_specs
    from .common import fail

    head, _, layout_text = episode.rpartition("/")
    episode_verb, _, obj = head.partition("/")
    if not (episode_verb and obj and layout_text.isdigit()):
        fail(f"--episode {episode!r}: use verb/object/layout as in the results JSON, e.g. cut/knife/1")
    if episode_verb != verb:
        fail(f"--episode {episode} is a {episode_verb!r} episode, not {verb!r}: pass --verb {episode_verb!r}")
    pair = next((p for p in pairs if p.object == obj), None)
    if pair is None:
        fail(f"--episode {episode}: {obj!r} is not among {verb!r}'s objects in {labels.path} "
             f"({', '.join(p.object for p in pairs)})")
    layout = int(layout_text)
    (spec,) = make_episode_specs(SimLabels(labels.path, (pair,), labels.affording), seed=seed,
                                 env_config=env_config, only_layout=layout)
    assert spec.id == episode, (spec.id, episode)
    return spec


def collision_meshes(
    out: Annotated[Path | None, typer.Option(help="Folder to write (default: the package's own "
                                                  "runtime/sim/collision, which scenes load).")] = None,
) -> None:
    """Rebuild the finer collision meshes of YCB objects whose shipped hulls fill an opening.

    Runs V-HACD on every YCB asset's visual mesh (~2 min), keeps those whose shipped hulls hold
    >= 1.3x the volume, and writes them with manifest.json (every asset's ratio). The output is
    deterministic: a rebuild of the shipped folder changes no byte.
    """
    from ..sim.assets import SharedAssetsMissingError
    from ..sim.collision_meshes import (
        COLLISION_DIR,
        MIN_VOLUME_RATIO,
        CollisionMeshError,
        build_collision_meshes,
    )
    from .common import fail, note

    target = out or COLLISION_DIR
    try:
        manifest = build_collision_meshes(target, progress=lambda a: note(f"decomposing {a}"))
    except (SharedAssetsMissingError, CollisionMeshError) as exc:
        fail(str(exc))
    used = sorted(a for a, e in manifest["assets"].items() if e["used"])
    note(f"wrote {target}: {len(used)} of {len(manifest['assets'])} YCB assets get finer meshes "
         f"(shipped/fine hull volume >= {MIN_VOLUME_RATIO}): {', '.join(used)}")
