"""An object wedged between the open fingers after the release is set down and freed
(``episode._unjam``, ``PickConfig.unjam_turn_deg``)."""

from __future__ import annotations

import dataclasses
import re

import pybullet as p
import pytest
from conftest import episode_spec

from craft_e.runtime.sim.episode import PickConfig


@pytest.mark.parametrize(("field", "value", "message"), [
    ("unjam_turn_deg", -5.0, "unjam_turn_deg -5.0 must be in [0, 90)"),
    ("unjam_turn_deg", 90.0, "unjam_turn_deg 90.0 must be in [0, 90)"),
    ("unjam_rise", 0.0, "unjam_rise 0.0 m must be > 0"),
])
def test_bad_unjam_settings_are_named(field: str, value: float, message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        PickConfig(**{field: value})


def test_a_sponge_wedged_in_the_open_hand_is_set_down_in_the_zone() -> None:
    """sim-dev's ``wipe/sponge/2`` at ``--seed 1``: the sponge (7.2 cm, the Franka hand opens 8)
    rides back up with the open fingers after the release. Without the step it comes to rest
    outside the zone (``docs/results/sim_dev_seed1.json`` before it); with it the hand sets it
    down, turns and lets it go. Same grasp, same scene, both ways."""
    from craft_e.paths import SIM_DEV_LABELS
    from craft_e.runtime.evaluation.sim_eval import (
        default_encoder,
    )
    from craft_e.runtime.sim.env import SimEnv
    from craft_e.runtime.sim.episode import Outcome, execute_pick
    from craft_e.runtime.sim.perceive import perceive
    from craft_e.runtime.sim.pipeline import PipelineConfig, relocated_grasp
    from craft_e.runtime.sim.surface import object_centre

    spec = episode_spec(SIM_DEV_LABELS, "wipe/sponge/2", seed=1)
    config = PipelineConfig()
    with SimEnv() as env:
        env.reset(spec.scene)
        env.robot.reset_home()
        perception = perceive(env, default_encoder(1), config)
        sponge = perception.target_roi
        assert sponge is not None and perception.rois[sponge].usable
        roi = perception.rois[sponge]
        start = p.saveState(physicsClientId=env.client)
        grasp, _ = relocated_grasp(env, perception.obs, roi, roi.usable[0], config)
        assert grasp.pose is not None
        centre = object_centre(perception.raised, roi.roi.mask)
        outcomes = {}
        for turn in (0.0, PickConfig().unjam_turn_deg):
            p.restoreState(stateId=start, physicsClientId=env.client)
            pick = dataclasses.replace(config.pick, unjam_turn_deg=turn)
            outcomes[turn] = execute_pick(env, grasp.pose, perception.target_body, pick, centre)
    off, on = outcomes[0.0], outcomes[20.0]
    assert off.outcome is Outcome.OUTSIDE_DROP_ZONE and off.detail == "target came to rest outside the drop zone"
    assert on.outcome is Outcome.SUCCESS, on.detail
    assert on.detail.startswith("it stayed wedged between the open fingers; set down, the hand turned")
