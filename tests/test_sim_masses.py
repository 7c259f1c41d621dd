"""Asset masses: the URDF converter's 1 g placeholder is read as unknown, every real mass stands."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pybullet as p
import pytest

from craft_e.runtime.sim import masses
from craft_e.runtime.sim.assets import ObjectAsset, object_asset, object_catalog
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.masses import (
    PLACEHOLDER_MASS_KG,
    AssetMassError,
    hull_volume,
    median_density,
    sim_mass,
    stated_mass,
)
from craft_e.runtime.sim.scene import SceneSpec


def test_only_the_marbles_state_the_placeholder() -> None:
    replaced = {a.asset_id for a in object_catalog().values() if sim_mass(a) is not None}
    assert replaced == {"a_marbles"}
    assert stated_mass(object_asset("a_marbles")) == PLACEHOLDER_MASS_KG
    # light real masses are kept as written
    assert sim_mass(object_asset("sponge")) is None
    assert stated_mass(object_asset("sponge")) == pytest.approx(0.0062)
    assert sim_mass(object_asset("dice")) is None


def test_the_marbles_get_their_volume_times_the_median_density() -> None:
    marbles = object_asset("a_marbles")
    density = median_density()
    assert 300.0 < density < 1500.0  # kg/m³: the catalogue is mostly solid household objects
    assert hull_volume(marbles) == pytest.approx(178e-6, rel=0.02)
    mass = sim_mass(marbles)
    assert mass == pytest.approx(hull_volume(marbles) * density)
    assert 0.05 < mass < 0.5  # type: ignore[operator]


def test_a_scene_body_carries_the_replaced_mass_and_the_rest_their_own() -> None:
    with SimEnv() as env:
        scene = env.reset(SceneSpec("play", "a_marbles", ("sponge", "mug"), seed=0))
        by_asset = {o.asset_id: o.body_id for o in scene.objects}
        marbles = p.getDynamicsInfo(by_asset["a_marbles"], -1, physicsClientId=env.client)
        assert marbles[0] == pytest.approx(sim_mass(object_asset("a_marbles")))
        # pybullet rescales the inertia with the mass: not the 1 g body's any more
        assert min(marbles[2]) > 1e-5
        for asset_id in ("sponge", "mug"):
            mass = p.getDynamicsInfo(by_asset[asset_id], -1, physicsClientId=env.client)[0]
            assert mass == pytest.approx(stated_mass(object_asset(asset_id)))


def _asset_with_mass(tmp_path: Path, mass_xml: str) -> ObjectAsset:
    """A copy of the marbles' URDF in ``tmp_path`` with its mass element replaced."""
    source = object_asset("a_marbles")
    text = source.urdf_path.read_text(encoding="utf-8")
    assert '<mass value="0.001" />' in text
    urdf = tmp_path / "edited.urdf"
    urdf.write_text(text.replace('<mass value="0.001" />', mass_xml), encoding="utf-8")
    (tmp_path / "a_marbles").symlink_to(source.urdf_path.parent / "a_marbles")
    return replace(source, asset_id="edited", urdf=str(urdf))  # an absolute path stays itself


def test_a_mass_that_is_not_a_number_names_the_file(tmp_path: Path) -> None:
    asset = _asset_with_mass(tmp_path, '<mass value="heavy" />')
    with pytest.raises(AssetMassError, match=r"edited\.urdf.*'heavy'.*kg"):
        stated_mass(asset)


def test_a_missing_mass_counts_as_unknown(tmp_path: Path) -> None:
    asset = _asset_with_mass(tmp_path, "")
    assert masses.is_placeholder(stated_mass(asset))
    assert sim_mass(asset) == pytest.approx(hull_volume(object_asset("a_marbles")) * median_density())


def test_the_marbles_are_picked_at_their_volume_mass_and_missed_at_the_placeholder_gram(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The cause, pinned on layout 0 of ``craft eval pickability --asset a_marbles``: with the
    hand's full 40 N, the same scene and pick with the URDF's 1 g closes on nothing, and with the
    volume mass it is picked. Since session 41 the hand closes gently on objects under 15 cm
    (``PickConfig.gentle_below``), and that grip holds even the 1 g heap: the same limit of the
    simulator on light bodies between stiff pads (``tests/test_gentle_grip.py``)."""
    import dataclasses

    from craft_e.runtime.evaluation.pickability import evaluate_pickability
    from craft_e.runtime.sim import scene
    from craft_e.runtime.sim.pipeline import PipelineConfig

    default = PipelineConfig()
    full_force = dataclasses.replace(default, pick=dataclasses.replace(default.pick, gentle_below=None))

    def outcome(config: PipelineConfig) -> str:
        report = evaluate_pickability(["a_marbles"], config=config, layouts=1)
        return report.outcome(report.episodes[0])

    assert outcome(full_force) == "success"
    assert outcome(default) == "success"
    monkeypatch.setattr(scene, "sim_mass", lambda asset: None)  # keep the stated 0.001 kg
    assert outcome(full_force) == "missed"
    assert outcome(default) == "success"


def test_an_evaluation_stops_on_a_bad_mass_with_the_file_and_writes_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    def bad(asset: ObjectAsset) -> float:
        raise AssetMassError(f"{asset.urdf_path}: <inertial><mass value='heavy'> is not a number; "
                             "give the link's mass in kg")

    monkeypatch.setattr(masses, "stated_mass", bad)
    out = tmp_path / "p.json"
    result = CliRunner().invoke(app, ["eval", "pickability", "--asset", "banana", "--layouts", "1",
                                      "--json", str(out)])
    assert result.exit_code == 2, result.output
    assert "banana.urdf" in result.output and "in kg" in result.output
    assert not out.exists()
