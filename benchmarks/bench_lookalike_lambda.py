"""How the look-alike cue's λ and κ were chosen (``grounding/lookalike_cue.py``), re-runnable.

The recognition protocol of ``craft eval recognition`` (74 assets × 3 seeded views, the 2x render's
whole square crop, p(o|r) over the 62 sim names): every view is rendered and encoded once, then
top-1/top-5 are computed for each (λ, κ) of the grid on top of two readings of p(o|r) at today's
defaults (the grounder's hubness correction and names in their sense, ConSE's class names in
theirs at temperature 2): the image alone, and with the depth cues the robot uses (size and
cavity), whose "no cue" row equals ``craft eval recognition``'s default row. It also reports how
often the look-alike answer of a view's true name lists the classifier's top-1 class.
λ = 0.5, κ = 1 (the shipped constants) was taken from this grid's plateau when it was first run
(Lite0, the size cue alone, none of the later readings; ``docs/recognition.md``). These are the
renders the cue is reported on: the grid picks constants on them, which ``docs/recognition.md``
states.

Why the readings are spelled out here: until 2026-12-07 the script read p(o|r) with the size cue
alone, without the cavity cue (a default since 2026-12-05), while its docstring still called its
shipped row ``craft eval recognition``'s "size + look-alike cue" row: its base matched no
recognition row any more.

Run: ``.venv/bin/python benchmarks/bench_lookalike_lambda.py [--json OUT] [--markdown OUT]`` (~2.5 min).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np
import numpy.typing as npt

from craft_e.arguments import number_list, output_file
from craft_e.paths import KB_DIR
from craft_e.runtime.encoders.conse import (
    ConSEImageEncoder,
    encode_with_classes,
    imagenet_class_names,
)
from craft_e.runtime.evaluation.common import vocabulary_senses
from craft_e.runtime.evaluation.recognition import render_views
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.grounding.lookalike_cue import (
    lookalike_log_likelihood,
    lookalike_table,
    with_lookalike_cue,
)
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.kb.bundle import Bundle, load_bundle
from craft_e.runtime.sim.assets import object_catalog
from craft_e.runtime.sim.pipeline import sim_vocabulary


def top_k_rates(p: np.ndarray, cols: list[int]) -> tuple[float, float]:
    """Top-1 and top-5 (percent) of each view's true name under ``p`` ``[N, O]``."""
    true = p[np.arange(len(cols)), cols]
    ranks = (p > true[:, None]).sum(axis=1)
    return round(100 * float(np.mean(ranks == 0)), 1), round(100 * float(np.mean(ranks < 5)), 1)


def base_readings(bundle: Bundle, vocabulary: list[str], embeddings: npt.NDArray[np.float32],
                  extents: npt.NDArray[np.float64], cavities: npt.NDArray[np.float64]) -> dict[bool, npt.NDArray[Any]]:
    """p(o|r) ``[N, O]`` the grid weighs with the cue: ``False`` the image alone, ``True`` with the
    size and cavity cues, both read as the evaluations' grounders read them (the day's defaults,
    names in the vocabulary's glosses, ``methods.build_grounders``). ``tests/test_bench_lookalike_lambda.py``
    holds the ``True`` reading to the evaluations' CRAFT-E grounder, so it cannot drift again."""
    senses = vocabulary_senses()
    return {depth: Grounder(bundle, GroundingSettings(vocabulary=vocabulary, size_cue=depth, cavity_cue=depth),
                            senses=senses).energies("cut", embeddings, extents=extents, cavities=cavities).p_obj
            for depth in (False, True)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--lambdas", type=number_list, default=[0.25, 0.5, 0.75, 0.9])
    parser.add_argument("--kappas", type=number_list, default=[0.5, 1.0])
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("--markdown", type=output_file, default=None)
    args = parser.parse_args()

    views = render_views(sorted(object_catalog()), 3, 0)
    emb, classes = encode_with_classes(ConSEImageEncoder(threads=1, preprocess="fit"), [v.crop_2x for v in views])
    extents = np.array([v.extents_m if v.extents_m is not None else (np.nan,) * 3 for v in views])
    vocabulary = list(sim_vocabulary())
    cols = [vocabulary.index(v.name) for v in views]
    bundle = load_bundle(KB_DIR / "craft-e-default", check_encoder=False)
    names = imagenet_class_names()
    cavities = np.array([np.nan if v.cavity_m is None else v.cavity_m for v in views])
    base = base_readings(bundle, vocabulary, emb, extents, cavities)
    hits = [bool(top) and names[top[0][0]] in dict(bundle.lookalikes[v.name]) for v, top in zip(views, classes, strict=True)]
    rows: list[dict[str, Any]] = [{"lambda": None, "kappa": None, "image": top_k_rates(base[False], cols),
                                   "depth_cues": top_k_rates(base[True], cols)}]
    for lam in args.lambdas:
        table = lookalike_table(vocabulary, bundle.lookalikes, names, lam)
        assert table is not None
        for kappa in args.kappas:
            ll = lookalike_log_likelihood(classes, table, kappa)
            rows.append({"lambda": lam, "kappa": kappa,
                         "image": top_k_rates(with_lookalike_cue(base[False], ll), cols),
                         "depth_cues": top_k_rates(with_lookalike_cue(base[True], ll), cols)})
    lines = ["### The look-alike cue's λ and κ on the recognition renders (top-1 / top-5, percent)", "",
             f"{len(views)} views; the classifier's top-1 class is listed in the true name's answer for "
             f"{100 * np.mean(hits):.1f} % of them.", "",
             "| λ | κ | image + cue | image, size and cavity cues + cue |", "|---:|---:|---:|---:|"]
    for r in rows:
        lam = "no cue" if r["lambda"] is None else f"{r['lambda']:g}"
        kap = "" if r["kappa"] is None else f"{r['kappa']:g}"
        lines.append(f"| {lam} | {kap} | {r['image'][0]} / {r['image'][1]} | {r['depth_cues'][0]} / {r['depth_cues'][1]} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.markdown:
        args.markdown.write_text(text, encoding="utf-8")
    if args.json:
        args.json.write_text(json.dumps({"views": len(views), "top1_class_in_answer": float(np.mean(hits)),
                                         "rows": rows}, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
