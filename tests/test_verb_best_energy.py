"""``benchmarks/verb_best_energy.py``: the per-verb best E_aff that docs/energy_weights.md quotes."""

from __future__ import annotations

from types import ModuleType

import pytest
from script_loader import load_benchmark


def _script() -> ModuleType:
    return load_benchmark("verb_best_energy")


def test_best_objects_of_the_sim_verbs_and_the_quoted_means() -> None:
    from craft_e.paths import SIM_DEV_LABELS, SIM_VAL_LABELS
    from craft_e.runtime.sim.pipeline import sim_vocabulary

    script, names = _script(), list(sim_vocabulary())
    dev = script.verb_bests("craft-e-default", SIM_DEV_LABELS, names)
    val = script.verb_bests("craft-e-default", SIM_VAL_LABELS, names)
    assert len(dev["verbs"]) == 12 and len(val["verbs"]) == 23
    for found in (dev, val):
        for verb, v in found["verbs"].items():
            # the bundle holds the 62 sim names, so its best object is at least as good
            assert -1.0 <= v["kb"][0] <= v["sim"][0] < 0, verb
            assert v["sim"][1] in names
    # the figures docs/energy_weights.md and the README quote (craft-e-default, unscaled)
    assert (dev["mean_sim"], dev["mean_kb"]) == pytest.approx((-0.815, -0.855), abs=0.001)
    assert (val["mean_sim"], val["mean_kb"]) == pytest.approx((-0.482, -0.620), abs=0.001)
    assert dev["verbs"]["hammer"]["sim"] == [pytest.approx(-0.99, abs=0.01), "hammer"]
