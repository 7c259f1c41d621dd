"""``craft eval recognition``: how often perception names a rendered testbed object right.

Every one of the 74 sim assets is placed alone on the testbed table ``views`` times (seeded
position and yaw, settled by physics) and seen by the testbed's overhead camera. Its crop (the
box of its true mask: this measures recognition, not segmentation) goes through the image encoder
and ``p(o | r)`` over the sim vocabulary (62 plain names) exactly as the grounder computes it; a
view is top-k correct when the asset's plain name is among the k most probable names. Asset names
never reach the encoder or the grounder: the table measures the open-world perception the robot
runs, not a per-asset prototype.

Settings (each row changes one thing over the row it builds on; the renders are shared):

* ``baseline``: 640x480 render, the crop resized 256 / centre 224 (the ImageNet transform);
* ``2x render``: the same view rendered at 1280x960 (a sharper colour sensor), crop from it;
* ``+ whole square crop``: the square crop with context resized to 224 as a whole (``fit``);
* ``+ mirror TTA``: probabilities averaged with the mirror image's;
* ``active look``: a second camera 0.35 m from the object at 45° elevation, from the robot's
  side (as an on-arm camera could move), alone and fused with the overhead view (mean of the
  two ConSE embeddings);
* ``2x fit + size cue``: the default view, with ``p(o | r)`` also weighed by how well the asset's
  extents, measured from the overhead depth, fit each name's typical size (the bundle's
  ``object_sizes.json``, one recorded answer per name; ``grounding/size_cue.py``).

The rows above run ConSE's first classifier, EfficientNet-Lite0 at 224x224; the ``Lite1`` rows run
the default since 2026-12-04, EfficientNet-Lite1 at its own 240x240 (``encoders/efficientnet.py``),
on the same renders.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from ..encoders.conse import ClassTop, ConSEImageEncoder
    from ..grounding.grounder import Grounder

LOOK_DISTANCE = 0.35  # m from the object's centre
LOOK_ELEVATION = 45.0  # degrees above the table


@dataclass(frozen=True)
class View:
    """One asset seen once: overhead colour crops at 1x and 2x, and the active look's crop."""

    asset: str
    name: str
    index: int
    crop_1x: npt.NDArray[np.uint8]
    crop_2x: npt.NDArray[np.uint8]
    crop_look: npt.NDArray[np.uint8]
    #: box edges from the overhead depth of the asset's raised points (``perception/extents.py``)
    extents_m: tuple[float, float, float] | None = None
    #: colour shares of the same raised pixels in the overhead colour image (``perception/colours.py``)
    colours: tuple[float, ...] | None = None
    #: how far the asset's inside lies below its rim in the overhead depth (``perception/cavity.py``)
    cavity_m: float | None = None


@dataclass(frozen=True)
class Setting:
    name: str
    description: str
    source: str  # "1x" | "2x" | "look" | "fused"
    preprocess: str = "center"
    tta: int = 1
    size_cue: bool = False
    colour_cue: bool = False
    lookalike_cue: bool = False
    classifier: str = "efficientnet-lite0"
    cavity_cue: bool = False
    hubness: bool = False  # grounding/hubness.py (every row before it was measured without)
    senses: bool = False  # grounding/senses.py: names read with their glosses (rows before it: names alone)
    #: encoders/conse.py: ConSE's ImageNet class names read with their WordNet glosses too (rows
    #: before it: the bare class names)
    class_senses: bool = False
    #: encoders/conse.py: the classifier's softmax temperature for ConSE's weights (rows before it: 1)
    conse_temperature: float = 1.0

    @property
    def cues(self) -> tuple[bool, bool, bool, bool, bool, bool, bool]:
        """What the setting's grounder weighs: the size, colour, look-alike and cavity cues, hubness,
        the names' senses and the class names' (which the hubness reference follows)."""
        return (self.size_cue, self.colour_cue, self.lookalike_cue, self.cavity_cue, self.hubness, self.senses,
                self.class_senses)


_LITE1 = "efficientnet-lite1"

SETTINGS: tuple[Setting, ...] = (
    Setting("baseline", "640x480 render, resize 256 / centre 224 (before issue 10)", "1x"),
    Setting("2x render", "the same view at 1280x960, crop from it", "2x"),
    Setting("+ whole square crop", "2x; the square crop with context resized to 224 (fit)", "2x", "fit"),
    Setting("+ mirror TTA", "2x, fit; probabilities averaged with the mirror image", "2x", "fit", 2),
    Setting("active look", "a second camera 0.35 m away at 45°, alone (fit)", "look", "fit"),
    Setting("overhead + active look", "mean embedding of the 2x fit view and the look (fit)", "fused", "fit"),
    Setting("2x fit + size cue", "2x, fit; p(o|r) weighed by the depth extents' fit to each name's "
            "typical size (object_sizes.json)", "2x", "fit", size_cue=True),
    Setting("2x fit + colour cue", "2x, fit; p(o|r) weighed by the ROI's colour shares' fit to each "
            "name's typical colours (object_colours.json)", "2x", "fit", colour_cue=True),
    Setting("2x fit + size + colour cue", "2x, fit; both cues", "2x", "fit", size_cue=True, colour_cue=True),
    Setting("2x fit + look-alike cue", "2x, fit; p(o|r) weighed by how well the classifier's ImageNet classes "
            "fit the classes each name's photos get (object_lookalikes.json)", "2x", "fit", lookalike_cue=True),
    Setting("2x fit + size + look-alike cue", "2x, fit; the size and look-alike cues", "2x", "fit",
            size_cue=True, lookalike_cue=True),
    Setting("Lite1, 2x fit", "the classifier EfficientNet-Lite1 at its 240x240 (2x, fit)", "2x", "fit",
            classifier=_LITE1),
    Setting("Lite1, 2x fit + size cue", "Lite1, 2x, fit, size cue: the default of 2026-12-04 (the cavity cue "
            "joined it on 2026-12-05)", "2x", "fit",
            size_cue=True, classifier=_LITE1),
    Setting("Lite1, 2x fit + size + colour cue", "Lite1, 2x, fit; the size and colour cues", "2x", "fit",
            size_cue=True, colour_cue=True, classifier=_LITE1),
    Setting("Lite1, 2x fit + size + look-alike cue", "Lite1, 2x, fit; the size and look-alike cues", "2x", "fit",
            size_cue=True, lookalike_cue=True, classifier=_LITE1),
    Setting("Lite1, active look + size cue", "Lite1, the look's view alone (fit), size cue", "look", "fit",
            size_cue=True, classifier=_LITE1),
    Setting("Lite1, overhead + active look + size cue", "Lite1, mean embedding of the 2x fit view and the look, "
            "size cue", "fused", "fit", size_cue=True, classifier=_LITE1),
    Setting("Lite1, 2x fit + size + cavity cue", "Lite1, 2x, fit; the size cue and the open cavity in the depth "
            "weighed against the KB's 'is concave' (grounding/cavity_cue.py): the default of 2026-12-05", "2x", "fit",
            size_cue=True, classifier=_LITE1, cavity_cue=True),
    Setting("Lite1, 2x fit + hubness", "Lite1, 2x, fit; each cosine less half the name's hubness, its mean cosine "
            "to its 10 nearest ImageNet class names (CSLS; grounding/hubness.py)", "2x", "fit", classifier=_LITE1,
            hubness=True),
    Setting("Lite1, 2x fit + size + cavity cue + hubness", "Lite1, 2x, fit; the size and cavity cues and the "
            "hubness correction: the default of 2026-12-06", "2x", "fit", size_cue=True, classifier=_LITE1,
            cavity_cue=True, hubness=True),
    Setting("Lite1, 2x fit + senses", "Lite1, 2x, fit; each name read with its gloss, the unit mean of the two "
            "embeddings (grounding/senses.py)", "2x", "fit", classifier=_LITE1, senses=True),
    Setting("Lite1, 2x fit + size + cavity cue + hubness + senses", "Lite1, 2x, fit; the size and cavity cues, "
            "the hubness correction and the names read with their glosses: the default of 2026-12-06 (later)",
            "2x", "fit", size_cue=True, classifier=_LITE1, cavity_cue=True, hubness=True, senses=True),
    Setting("Lite1, 2x fit + senses, both sides", "Lite1, 2x, fit; the names and ConSE's ImageNet class "
            "names each read with their gloss (encoders/conse.py: the classes' WordNet glosses)", "2x", "fit",
            classifier=_LITE1, senses=True, class_senses=True),
    Setting("Lite1, 2x fit + size + cavity cue + hubness + senses, both sides", "Lite1, 2x, fit; the size "
            "and cavity cues, the hubness correction and the names and class names read with their glosses: "
            "the default of 2026-12-06 (session 33)", "2x", "fit", size_cue=True, classifier=_LITE1,
            cavity_cue=True, hubness=True, senses=True, class_senses=True),
    Setting("Lite1, 2x fit + senses, both sides + ConSE T=2", "Lite1, 2x, fit; the names and class names read "
            "with their glosses, ConSE's weights the classifier's softmax at temperature 2 (encoders/conse.py)",
            "2x", "fit", classifier=_LITE1, senses=True, class_senses=True, conse_temperature=2.0),
    Setting("Lite1, 2x fit + size + cavity cue + hubness + senses, both sides + ConSE T=2", "Lite1, 2x, fit; "
            "the size and cavity cues, the hubness correction, the names and class names read with their "
            "glosses and ConSE's weights at temperature 2: the default since 2026-12-06 (session 34)", "2x", "fit",
            size_cue=True, classifier=_LITE1, cavity_cue=True, hubness=True, senses=True, class_senses=True,
            conse_temperature=2.0),
)


def _box(mask: npt.NDArray[np.bool_]) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(mask)
    return int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)


def render_views(assets: Sequence[str], views: int = 3, seed: int = 0,
                 progress: Callable[[int, int], None] | None = None) -> list[View]:
    """Each asset alone on the table ``views`` times, in one pybullet client of its own."""
    import pybullet as p

    from ..encoders.image import crop_box
    from ..perception.cavity import measure_cavity
    from ..perception.colours import measure_colours
    from ..perception.extents import measure_extents
    from ..sim.assets import object_catalog
    from ..sim.camera import Camera, render
    from ..sim.fingers import FingerGeometry
    from ..sim.perceive import raised_mask
    from ..sim.scene import SceneSpec, TableLayout, make_scene

    catalog = object_catalog()
    camera, layout, fingers = Camera(), TableLayout(), FingerGeometry()
    sharp = camera.scaled(2)
    out: list[View] = []
    client = p.connect(p.DIRECT)
    try:
        for n, asset in enumerate(assets):
            for v in range(views):
                p.resetSimulation(physicsClientId=client)
                p.setGravity(0.0, 0.0, -9.81, physicsClientId=client)
                scene = make_scene(SceneSpec("see", asset, (), seed * 100_003 + n * 101 + v), client,
                                   layout, camera)
                body = scene.target.body_id
                obs = render(client, camera)
                assert obs.seg is not None
                box = _box(np.asarray(obs.seg == body))
                rgb2 = render(client, sharp).rgb
                lo, hi = p.getAABB(body, physicsClientId=client)
                centre = (np.asarray(lo) + np.asarray(hi)) / 2
                e = np.radians(LOOK_ELEVATION)
                eye = centre + LOOK_DISTANCE * np.array([-np.cos(e), 0.0, np.sin(e)])
                look_cam = Camera(eye=(float(eye[0]), float(eye[1]), float(eye[2])),
                                  target=(float(centre[0]), float(centre[1]), float(centre[2])),
                                  up=(0.0, 0.0, 1.0))
                look = render(client, look_cam)
                assert look.seg is not None
                look_mask = look.seg == body
                crop_look = (crop_box(look.rgb, _box(look_mask)) if look_mask.any()
                             else obs.rgb[:1, :1])
                world = obs.points_world()
                surface = (obs.seg == body) & raised_mask(world, layout.table_z, fingers.height_tolerance)
                out.append(View(asset, catalog[asset].name, v, crop_box(obs.rgb, box),
                                crop_box(rgb2, tuple(2 * x for x in box)), crop_look,
                                measure_extents(world[surface], layout.table_z),
                                measure_colours(obs.rgb[surface]),
                                measure_cavity(world[..., 2] - layout.table_z, surface)))
            if progress is not None:
                progress(n + 1, len(assets))
    finally:
        p.disconnect(physicsClientId=client)
    return out


@dataclass
class RecognitionReport:
    rows: list[dict[str, Any]]
    per_asset: dict[str, dict[str, int]]  # setting -> asset -> views named right (top-1)
    config: dict[str, Any]
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"benchmark": "recognition of rendered testbed objects", "config": self.config,
                "settings": self.rows, "per_asset_top1": self.per_asset, "notes": self.notes}

    def to_markdown(self) -> str:
        c = self.config
        lines = [f"### Recognition of rendered testbed objects: {c['assets']} assets × {c['views']} views "
                 f"= {c['images']} images, p(o|r) over {c['vocabulary_size']} names (T = {c['temperature']})\n",
                 "| setting | what changes | top-1 % | top-5 % | encoder ms / ROI |",
                 "|---|---|---:|---:|---:|"]
        for r in self.rows:
            lines.append(f"| {r['setting']} | {r['description']} | {100 * r['top1']:.1f} | "
                         f"{100 * r['top5']:.1f} | {r['encoder_ms_per_roi']:.0f} |")
        out = "\n".join(lines) + "\n"
        if self.notes:
            out += "\n" + "\n".join(f"- {n}" for n in self.notes) + "\n"
        return out


def _ranks(grounder: Grounder, emb: npt.NDArray[np.float32], names: Sequence[str],
           extents: npt.NDArray[np.float64] | None = None,
           colours: npt.NDArray[np.float64] | None = None,
           classes: Sequence[ClassTop | None] | None = None,
           cavities: npt.NDArray[np.float64] | None = None) -> npt.NDArray[np.int64]:
    """Rank (0 = top) of each view's true name under p(o|r)."""
    p = grounder.energies(grounder.verbs[0], emb, extents=extents, colours=colours, classes=classes,
                          cavities=cavities).p_obj  # [N, O]; the verb does not enter p
    cols = [grounder.vocabulary.index(n) for n in names]
    true = p[np.arange(len(names)), cols]
    return np.asarray((p > true[:, None]).sum(axis=1), dtype=np.int64)


def evaluate_recognition(views: int = 3, seed: int = 0, *, threads: int = 1,
                         progress: Callable[[int, int], None] | None = None) -> RecognitionReport:
    """Render every asset, then score every setting of ``SETTINGS`` on the same renders."""
    import torch

    from ...paths import KB_DIR
    from ..encoders.conse import DEFAULT_CLASS_SENSE_WEIGHT, ConSEImageEncoder, encode_with_classes
    from ..grounding.grounder import Grounder
    from ..grounding.settings import DEFAULT_SENSE_WEIGHT, GroundingSettings
    from ..kb.bundle import load_bundle
    from ..kb.colours import COLOUR_TERMS
    from ..sim.assets import object_catalog
    from ..sim.pipeline import sim_vocabulary
    from .common import vocabulary_senses

    bundle = load_bundle(KB_DIR / "craft-e-default", check_encoder=False)  # before the renders: fail fast
    assets = sorted(object_catalog())
    rendered = render_views(assets, views, seed, progress)
    senses = vocabulary_senses()  # the glosses every evaluation reads names in (methods.build_grounders)
    grounders = {s.cues: Grounder(bundle, GroundingSettings(
        vocabulary=list(sim_vocabulary()), size_cue=s.size_cue, colour_cue=s.colour_cue, lookalikes=s.lookalike_cue,
        cavity_cue=s.cavity_cue, hubness=s.hubness, sense_weight=DEFAULT_SENSE_WEIGHT if s.senses else 0.0,
        class_sense_weight=DEFAULT_CLASS_SENSE_WEIGHT if s.class_senses else 0.0),
        senses=senses) for s in SETTINGS}
    grounder = grounders[(False,) * 7]
    extents = np.array([v.extents_m if v.extents_m is not None else (np.nan,) * 3 for v in rendered])
    colours = np.array([v.colours if v.colours is not None else (np.nan,) * len(COLOUR_TERMS) for v in rendered])
    cavities = np.array([np.nan if v.cavity_m is None else v.cavity_m for v in rendered])
    names = [v.name for v in rendered]
    encoders: dict[tuple[str, str, int, bool, float], ConSEImageEncoder] = {}
    rows: list[dict[str, Any]] = []
    per_asset: dict[str, dict[str, int]] = {}
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        for s in SETTINGS:
            key = (s.classifier, s.preprocess, s.tta, s.class_senses, s.conse_temperature)
            enc = encoders.get(key)
            if enc is None:
                enc = encoders[key] = ConSEImageEncoder(
                    threads=threads, preprocess=s.preprocess, tta=s.tta, classifier=s.classifier,
                    sense_weight=DEFAULT_CLASS_SENSE_WEIGHT if s.class_senses else 0.0,
                    temperature=s.conse_temperature)
            start = time.perf_counter()
            classes: list[ClassTop | None] | None = None  # the fused view has no single classifier output
            if s.source == "fused":
                a = enc.embed_images([v.crop_2x for v in rendered])
                b = enc.embed_images([v.crop_look for v in rendered])
                emb = np.asarray((a + b) / 2, dtype=np.float32)
                rois = 2 * len(rendered)
            else:
                attr = {"1x": "crop_1x", "2x": "crop_2x", "look": "crop_look"}[s.source]
                emb, classes = encode_with_classes(enc, [getattr(v, attr) for v in rendered])
                rois = len(rendered)
            ms = 1000 * (time.perf_counter() - start) / rois
            ranks = _ranks(grounders[s.cues], emb, names,
                           extents if s.size_cue else None, colours if s.colour_cue else None,
                           classes if s.lookalike_cue else None, cavities if s.cavity_cue else None)
            rows.append({"setting": s.name, "description": s.description, "source": s.source,
                         "preprocess": s.preprocess, "tta": s.tta, "encoder_id": enc.id,
                         "top1": round(float(np.mean(ranks == 0)), 6),
                         "top5": round(float(np.mean(ranks < 5)), 6),
                         "encoder_ms_per_roi": round(ms, 1)})
            hits: dict[str, int] = {}
            for v, r in zip(rendered, ranks.tolist(), strict=True):
                hits[v.asset] = hits.get(v.asset, 0) + int(r == 0)
            per_asset[s.name] = hits
    finally:
        torch.set_num_threads(previous)
    config = {"assets": len(assets), "views": views, "images": len(rendered), "seed": seed,
              "vocabulary_size": len(grounder.vocabulary), "temperature": grounder.temperature,
              "kb": grounder.kb, "threads": threads}
    notes = ["Encoder time is wall-clock on this host (not part of any result's identity); "
             "the active look's extra render and arm motion are not counted here."]
    return RecognitionReport(rows, per_asset, config, notes)
