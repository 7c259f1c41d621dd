"""Finer collision meshes for objects whose shipped hulls fill an opening (sim/collision_meshes.py).

Why: the YCB mug, bowl and cups collide through 4 coarse hulls that span their mouths, so rim
grasps the robot's checks rightly accept came down on an invisible lid. These tests pin the
shipped meshes to the rule that chose them and to the shared assets they were built from, show
that the openings are open to physics (vertical rays reach the floor of a mug, a bowl and the
cups, which the shipped hulls stop near the rim), and that scenes load them.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pybullet as p
import pytest

from craft_e.runtime.sim.assets import object_asset, object_catalog
from craft_e.runtime.sim.collision_meshes import (
    COLLISION_DIR,
    MIN_VOLUME_RATIO,
    CollisionMeshError,
    decompose,
    fine_mesh,
    hulls_volume,
    obj_parts,
    rays_reaching_low,
    shipped_manifest,
    shipped_parts,
    sim_urdf,
    visual_mesh_file,
)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_the_manifest_covers_every_ycb_asset_and_follows_its_rule() -> None:
    manifest = shipped_manifest()
    ycb = {a for a, asset in object_catalog().items() if asset.source == "ycb"}
    assert set(manifest["assets"]) == ycb
    assert manifest["min_volume_ratio"] == MIN_VOLUME_RATIO
    for asset_id, entry in manifest["assets"].items():
        assert entry["used"] == (entry["ratio"] >= MIN_VOLUME_RATIO), asset_id
        assert entry["visual_sha256"] == _sha(visual_mesh_file(object_asset(asset_id))), (
            f"{asset_id}: the shared visual mesh changed; rebuild with `craft sim collision-meshes`")
        mesh = fine_mesh(asset_id)
        assert (mesh is not None) == entry["used"]
        if mesh is not None:
            assert _sha(mesh) == entry["mesh_sha256"]
    used = {a for a, e in manifest["assets"].items() if e["used"]}
    assert {"mug", "bowl", "a_cups"} <= used  # the open vessels
    assert not used & {"apple", "cracker_box", "tomato_soup_can", "tennis_ball"}  # solid objects keep theirs
    assert {p.name for p in COLLISION_DIR.glob("*.obj")} == {f"{a}.obj" for a in used}


def test_the_mug_ratio_is_recomputed_from_the_files() -> None:
    entry = shipped_manifest()["assets"]["mug"]
    shipped = hulls_volume(shipped_parts(object_asset("mug")))
    fine = hulls_volume(obj_parts(COLLISION_DIR / "mug.obj"))
    assert round(shipped * 1e6, 1) == entry["shipped_cm3"]
    assert round(fine * 1e6, 1) == entry["fine_cm3"]
    assert shipped / fine > 1.5  # the shipped hulls hold twice the mug's volume: its mouth


def test_decomposition_is_deterministic_and_reproduces_the_shipped_file(tmp_path: Path) -> None:
    visual = visual_mesh_file(object_asset("a_cups"))
    a, b = tmp_path / "a.obj", tmp_path / "b.obj"
    decompose(visual, a)
    decompose(visual, b)
    assert a.read_bytes() == b.read_bytes() == (COLLISION_DIR / "a_cups.obj").read_bytes()


@pytest.mark.parametrize(("asset_id", "shipped_at_most", "fine_at_least"),
                         [("mug", 5, 40), ("bowl", 5, 200), ("a_cups", 30, 120)])
def test_the_openings_are_open_to_physics(asset_id: str, shipped_at_most: int, fine_at_least: int) -> None:
    assert rays_reaching_low(object_asset(asset_id), fine_collision=False) <= shipped_at_most  # stopped by a lid of hulls
    assert rays_reaching_low(object_asset(asset_id), fine_collision=True) >= fine_at_least  # down to the floor inside


def test_the_derived_urdf_keeps_visual_and_mass() -> None:
    asset = object_asset("mug")
    assert sim_urdf(asset, fine_collision=False) == asset.urdf_path
    derived = sim_urdf(asset)
    assert derived != asset.urdf_path and derived.exists()
    client = p.connect(p.DIRECT)
    try:
        shipped_body = p.loadURDF(str(asset.urdf_path), physicsClientId=client)
        fine_body = p.loadURDF(str(derived), physicsClientId=client)
        shipped_dyn, fine_dyn = (p.getDynamicsInfo(b, -1, physicsClientId=client) for b in (shipped_body, fine_body))
        assert shipped_dyn[0] == fine_dyn[0]  # mass, from the URDF
        # pybullet derives the inertia from the collision shape (not the URDF's), so it moves a little
        np.testing.assert_allclose(fine_dyn[2], shipped_dyn[2], rtol=0.15)
        vis = [p.getVisualShapeData(b, physicsClientId=client)[0][4:8] for b in (shipped_body, fine_body)]
        assert vis[0] == vis[1]  # the same mesh file, scale and origin
    finally:
        p.disconnect(physicsClientId=client)
    assert sim_urdf(object_asset("apple")) == object_asset("apple").urdf_path  # solid: shipped hulls


def test_a_listed_mesh_that_is_missing_is_a_clear_error(tmp_path: Path) -> None:
    manifest = {"assets": {"mug": {"used": True}}}
    (tmp_path / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    with pytest.raises(CollisionMeshError, match=r"mug\.obj.*craft sim collision-meshes"):
        fine_mesh("mug", tmp_path)
    assert fine_mesh("apple", tmp_path) is None


def test_a_build_never_replaces_a_folder_that_is_not_its_own(tmp_path: Path) -> None:
    """``craft sim collision-meshes --out DIR`` swaps its result into DIR: a user's folder there
    must survive untouched, with an error saying what to do (checked before any decomposition)."""
    from craft_e.runtime.sim.collision_meshes import build_collision_meshes

    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("keep me", encoding="utf-8")
    with pytest.raises(CollisionMeshError, match=r"theirs.*not a collision-mesh build.*--out"):
        build_collision_meshes(theirs)
    assert (theirs / "notes.txt").read_text(encoding="utf-8") == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["theirs"]  # no staging folder left

    mixed = tmp_path / "mixed"  # a build of ours with someone's file added: not ours either
    shutil.copytree(COLLISION_DIR, mixed)
    (mixed / "notes.txt").write_text("keep me", encoding="utf-8")
    with pytest.raises(CollisionMeshError):
        build_collision_meshes(mixed)
    assert (mixed / "notes.txt").exists()
    a_file = tmp_path / "file.obj"
    a_file.write_text("v 0 0 0\n", encoding="utf-8")
    with pytest.raises(CollisionMeshError):
        build_collision_meshes(a_file)
    assert a_file.read_text(encoding="utf-8") == "v 0 0 0\n"


def test_a_rebuild_swaps_in_and_a_failed_one_keeps_the_old(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Into a previous build of ours the new one is swapped in whole; a build that fails half-way
    leaves the previous one as it was and no staging folder behind."""
    import craft_e.runtime.sim.collision_meshes as cm

    out = tmp_path / "collision"
    shutil.copytree(COLLISION_DIR, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    calls: list[str] = []

    def fake_decompose(visual: Path, target: Path) -> None:
        calls.append(visual.parent.name)
        if len(calls) == 3:
            raise CollisionMeshError("V-HACD failed")
        target.write_text("o convex_0\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n", encoding="utf-8")

    monkeypatch.setattr(cm, "decompose", fake_decompose)
    with pytest.raises(CollisionMeshError, match="V-HACD failed"):
        cm.build_collision_meshes(out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["collision"]

    calls.clear()
    monkeypatch.setattr(cm, "decompose", lambda visual, target: target.write_text(
        "o convex_0\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n", encoding="utf-8"))
    manifest = cm.build_collision_meshes(out)
    assert json.loads((out / "manifest.json").read_text(encoding="utf-8")) == manifest
    assert sorted(p.name for p in tmp_path.iterdir()) == ["collision"]  # the old build is gone
