"""Collision shapes that keep the openings the camera sees: a mug's mouth, a clamp's jaws.

Every YCB asset in ``shared/`` collides through 1–4 coarse convex hulls (CoACD parts of ~32
triangles each). For a solid object that is close to its visual mesh; for a vessel, or an object
with a gap, the hulls fill what the camera sees as empty. The mug's four hulls span its mouth, so
a rim grasp (one finger inside, the way people hold a mug and the way the grasp checks allow it)
came down on an invisible lid: on the dev scenes the fingers stopped 1–4 cm above such grasps,
and 6 of CRAFT-E's 13 execution failures were mug picks (docs/results/sim_execution.md).

The rule, from geometry alone: an asset collides through a finer decomposition (pybullet's
V-HACD of its visual mesh, ``VHACD_PARAMS``) when its shipped hulls hold at least
``MIN_VOLUME_RATIO`` times the volume of the finer ones, i.e. they fill space the object does not
occupy. ``build_collision_meshes`` measures every YCB asset, writes the chosen decompositions and a
``manifest.json`` with every asset's ratio (``craft sim collision-meshes``); the files ship as
package data, so scenes never run V-HACD. ``sim_urdf`` gives ``make_scene`` a copy of the asset's
URDF whose collision is the finer mesh (visual, mass and inertia unchanged).

This changes the simulator's physics, not the robot: nothing here reaches perception, grounding
or the grasp checks, which see rendered pixels only.
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import json
import multiprocessing.util
import os
import shutil
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pybullet as p
from scipy.spatial import ConvexHull, QhullError

from .assets import ObjectAsset, object_catalog

FloatArray = npt.NDArray[np.float64]

COLLISION_DIR = Path(__file__).with_name("collision")
MANIFEST_NAME = "manifest.json"
MIN_VOLUME_RATIO = 1.3
VHACD_PARAMS: dict[str, float | int] = {"resolution": 200_000, "concavity": 0.0025, "maxNumVerticesPerCH": 64}


class CollisionMeshError(RuntimeError):
    """A shipped collision mesh or its manifest is missing or does not match the assets."""


# ---------------------------------------------------------------------------------------------
# reading meshes


def stl_vertices(path: Path) -> FloatArray:
    """``[3n, 3]`` triangle corners of a binary STL file."""
    data = path.read_bytes()
    count = int.from_bytes(data[80:84], "little")
    if len(data) < 84 + 50 * count:
        raise CollisionMeshError(f"{path}: truncated binary STL ({len(data)} bytes for {count} triangles)")
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attr", "<u2")])
    triangles = np.frombuffer(data, dtype=record, count=count, offset=84)
    return triangles["corners"].reshape(-1, 3).astype(np.float64)


def obj_parts(path: Path) -> list[FloatArray]:
    """The vertices of each ``o`` group of an OBJ file (pybullet makes one convex hull of each)."""
    vertices: list[list[float]] = []
    groups: list[list[int]] = []
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("o "):
            groups.append([])
        elif line.startswith("v ") and groups:
            vertices.append([float(x) for x in line.split()[1:4]])
            groups[-1].append(len(vertices) - 1)
    table = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    return [table[g] for g in groups if g]


def hulls_volume(parts: list[FloatArray]) -> float:
    """Summed volume (m³) of the parts' convex hulls; a flat or tiny part counts as 0."""
    total = 0.0
    for points in parts:
        if len(points) < 4:
            continue
        with contextlib.suppress(QhullError):
            total += float(ConvexHull(points).volume)
    return total


def urdf_link(asset: ObjectAsset) -> tuple[ET.Element, ET.Element]:
    """(root, its one ``<link>``) of the asset's URDF."""
    root = ET.parse(asset.urdf_path).getroot()
    link = root.find("link")
    if link is None:
        raise CollisionMeshError(f"{asset.urdf_path}: no <link>")
    return root, link


def shipped_collision_files(asset: ObjectAsset) -> list[Path]:
    """The mesh files of the asset's URDF ``<collision>`` elements."""
    _, link = urdf_link(asset)
    base = asset.urdf_path.parent
    return [base / str(m.get("filename")) for m in link.findall("collision/geometry/mesh")]


def shipped_parts(asset: ObjectAsset) -> list[FloatArray]:
    """The vertices of each convex part pybullet builds from the shipped collision meshes."""
    parts: list[FloatArray] = []
    for path in shipped_collision_files(asset):
        if path.suffix.lower() == ".stl":
            parts.append(stl_vertices(path))
        else:
            parts.extend(obj_parts(path))
    return parts


def visual_mesh_file(asset: ObjectAsset) -> Path:
    """The asset's visual mesh (what the camera renders)."""
    _, link = urdf_link(asset)
    mesh = link.find("visual/geometry/mesh")
    if mesh is None:
        raise CollisionMeshError(f"{asset.urdf_path}: no visual mesh")
    return asset.urdf_path.parent / str(mesh.get("filename"))


# ---------------------------------------------------------------------------------------------
# building (craft sim collision-meshes)


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """V-HACD prints its whole log to the process's stdout (C level): send it to /dev/null."""
    import sys

    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        try:
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)


def decompose(visual: Path, out: Path) -> None:
    """V-HACD of ``visual`` into ``out`` (deterministic: the same bytes for the same inputs)."""
    client = p.connect(p.DIRECT)
    try:
        with tempfile.TemporaryDirectory() as tmp, _quiet_stdout():
            p.vhacd(str(visual), str(out), str(Path(tmp) / "vhacd.log"), physicsClientId=client,
                    **VHACD_PARAMS)
    finally:
        p.disconnect(physicsClientId=client)
    if not out.exists() or not obj_parts(out):
        raise CollisionMeshError(f"V-HACD wrote no convex parts for {visual}")


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _ours(folder: Path) -> bool:
    """Is ``folder`` absent, empty, or a collision-mesh folder this module wrote (its manifest and
    ``.obj`` files only)? Anything else is not ours to replace."""
    if not folder.exists():
        return True
    if not folder.is_dir():
        return False
    names = {f.name for f in folder.iterdir()}
    if not names:
        return True
    try:
        manifest = json.loads((folder / MANIFEST_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return (isinstance(manifest, dict) and {"min_volume_ratio", "vhacd", "assets"} <= manifest.keys()
            and all(n == MANIFEST_NAME or n.endswith(".obj") for n in names))


def _measure(asset: ObjectAsset, fine: Path) -> dict[str, Any]:
    """Decompose ``asset`` into ``fine`` and compare its volume with the shipped hulls'."""
    visual = visual_mesh_file(asset)
    decompose(visual, fine)
    shipped_hulls, fine_hulls = shipped_parts(asset), obj_parts(fine)
    shipped, finer = hulls_volume(shipped_hulls), hulls_volume(fine_hulls)
    ratio = shipped / finer if finer > 0 else 0.0
    return {"visual_sha256": _sha256(visual), "shipped_parts": len(shipped_hulls),
            "fine_parts": len(fine_hulls), "shipped_cm3": round(shipped * 1e6, 1),
            "fine_cm3": round(finer * 1e6, 1), "ratio": round(ratio, 3), "used": ratio >= MIN_VOLUME_RATIO}


def build_collision_meshes(out_dir: Path, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Measure every YCB asset and write the finer meshes it needs plus ``manifest.json``.

    Written into a temporary folder beside ``out_dir`` and swapped in at the end, so an
    interrupted build leaves ``out_dir`` as it was. ``out_dir`` must be new, empty, or a folder
    this function wrote before: anything else raises ``CollisionMeshError`` and is left
    untouched. Returns the manifest.
    """
    if not _ours(out_dir):
        raise CollisionMeshError(f"{out_dir} holds files that are not a collision-mesh build (no manifest.json "
                                 "of ours, or other files); choose a new or empty folder with --out")
    assets = sorted((a for a in object_catalog().values() if a.source == "ycb"), key=lambda a: a.asset_id)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".collision-", dir=out_dir.parent))
    try:
        entries: dict[str, dict[str, Any]] = {}
        for asset in assets:
            if progress is not None:
                progress(asset.asset_id)
            fine = staging / f"{asset.asset_id}.obj"
            entry = _measure(asset, fine)
            if entry["used"]:
                entry["mesh_sha256"] = _sha256(fine)
            else:
                fine.unlink()
            entries[asset.asset_id] = entry
        manifest = {
            "description": "Finer collision meshes for YCB assets whose shipped convex hulls fill "
                           "openings (runtime/sim/collision_meshes.py). ratio = shipped hull volume / "
                           "V-HACD hull volume; used when ratio >= min_volume_ratio.",
            "min_volume_ratio": MIN_VOLUME_RATIO, "vhacd": VHACD_PARAMS, "pybullet_api": p.getAPIVersion(),
            "assets": entries,
        }
        (staging / MANIFEST_NAME).write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n", encoding="utf-8")
        _swap_in(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return manifest


def _swap_in(staging: Path, out_dir: Path) -> None:
    """Put ``staging`` at ``out_dir``; a previous build there is moved aside first and deleted
    only once the new one is in place (restored if the move fails)."""
    if not out_dir.exists():
        staging.rename(out_dir)
        return
    old = Path(tempfile.mkdtemp(prefix=".collision-old-", dir=out_dir.parent))
    old.rmdir()
    out_dir.rename(old)
    try:
        staging.rename(out_dir)
    except BaseException:
        old.rename(out_dir)
        raise
    shutil.rmtree(old, ignore_errors=True)


# ---------------------------------------------------------------------------------------------
# using them (make_scene)


@cache
def shipped_manifest(directory: Path = COLLISION_DIR) -> dict[str, Any]:
    """The manifest shipped beside this module (read once per process)."""
    path = directory / MANIFEST_NAME
    if not path.exists():
        raise CollisionMeshError(f"{path} is missing; rebuild it with `craft sim collision-meshes`")
    manifest: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    return manifest


def fine_mesh(asset_id: str, directory: Path = COLLISION_DIR) -> Path | None:
    """The finer collision mesh ``asset_id`` collides through, or None for its shipped hulls."""
    entry = shipped_manifest(directory)["assets"].get(asset_id)
    if entry is None or not entry["used"]:
        return None
    path = directory / f"{asset_id}.obj"
    if not path.exists():
        raise CollisionMeshError(f"{path} is listed in {directory / MANIFEST_NAME} but missing; "
                                 "rebuild with `craft sim collision-meshes`")
    return path


@cache
def _derived_dir() -> Path:
    """This process's folder of derived URDFs, removed when it exits: ``atexit`` in a main
    process, the multiprocessing finalizer in an evaluation worker (workers skip atexit)."""
    path = Path(tempfile.mkdtemp(prefix="craft-e-urdf-"))
    atexit.register(shutil.rmtree, path, True)
    multiprocessing.util.Finalize(None, shutil.rmtree, args=(path, True), exitpriority=0)
    return path


def derived_urdf_text(asset: ObjectAsset, mesh: Path) -> str:
    """The asset's URDF with every ``<collision>`` replaced by one on ``mesh`` (same origin and
    scale as the shipped ones) and every file path made absolute."""
    root, link = urdf_link(asset)
    base = asset.urdf_path.parent.resolve()
    shipped = link.findall("collision")
    if not shipped:
        raise CollisionMeshError(f"{asset.urdf_path}: no <collision> to replace")
    first = shipped[0]
    for element in shipped:
        link.remove(element)
    for mesh_el in link.iter("mesh"):
        mesh_el.set("filename", str(base / str(mesh_el.get("filename"))))
    collision = ET.Element("collision")
    origin = first.find("origin")
    if origin is not None:
        collision.append(origin)
    geometry = ET.SubElement(collision, "geometry")
    scale = first.find("geometry/mesh")
    ET.SubElement(geometry, "mesh", filename=str(mesh.resolve()),
                  scale=(scale.get("scale") if scale is not None else None) or "1 1 1")
    inertial = link.find("inertial")
    link.insert(list(link).index(inertial) if inertial is not None else len(link), collision)
    text: str = ET.tostring(root, encoding="unicode")
    return text


def sim_urdf(asset: ObjectAsset, fine_collision: bool = True) -> Path:
    """The URDF the simulator loads for ``asset``: the shipped one, or (``fine_collision`` and a
    finer mesh shipped for it) a derived copy in a per-process temporary folder."""
    mesh = fine_mesh(asset.asset_id) if fine_collision else None
    if mesh is None:
        return asset.urdf_path
    path = _derived_dir() / f"{asset.asset_id}.urdf"
    if not path.exists():
        tmp = path.with_suffix(".tmp")
        tmp.write_text(derived_urdf_text(asset, mesh), encoding="utf-8")
        tmp.replace(path)
    return path


def rays_reaching_low(asset: ObjectAsset, fine_collision: bool, grid: int = 30, low_share: float = 0.3) -> int:
    """How many of ``grid`` x ``grid`` vertical rays over the asset's box hit it in its lowest
    ``low_share`` of height: what fingers can reach inside an opening (the asset alone, unrotated,
    in a private client). The shipped mug hulls let 3 of 900 through, its fine mesh 55."""
    client = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(str(sim_urdf(asset, fine_collision)), physicsClientId=client)
        lo, hi = p.getAABB(body, -1, physicsClientId=client)
        xs, ys = np.meshgrid(np.linspace(lo[0], hi[0], grid), np.linspace(lo[1], hi[1], grid))
        starts = [[x, y, hi[2] + 0.05] for x, y in zip(xs.ravel(), ys.ravel(), strict=True)]
        ends = [[x, y, lo[2] - 0.01] for x, y in zip(xs.ravel(), ys.ravel(), strict=True)]
        hits = p.rayTestBatch(starts, ends, physicsClientId=client)
        low = lo[2] + low_share * (hi[2] - lo[2])
        return sum(1 for h in hits if h[0] == body and h[3][2] < low)
    finally:
        p.disconnect(physicsClientId=client)
