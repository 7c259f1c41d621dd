"""Do the vessels' collision shapes have the cavity the camera sees? (issue 10, item 3)

For each open vessel (bowls, mugs, cup, plate, pitcher) alone on the table: the height of its rim,
and the lowest surface within 2 cm of its centre as the rendered depth image shows it (visual
mesh) and as vertical rays on the collision shape find it (what the fingers meet in physics).
A rim grasp puts one finger inside; it can only work where the collision floor is low too.
The last two columns count, of 30 x 30 vertical rays over the asset's box, those that reach its
lowest 30 % with the shipped hulls and with the collision the testbed loads
(``collision_meshes.rays_reaching_low``: the whole mouth, not only its centre).

Run: ``.venv/bin/python benchmarks/vessel_cavities.py``.
"""

from __future__ import annotations

import argparse

import numpy as np

from craft_e.runtime.sim.assets import object_catalog
from craft_e.runtime.sim.collision_meshes import rays_reaching_low
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.oracle import top_surface_points
from craft_e.runtime.sim.scene import SceneSpec

VESSELS = ("bowl", "mug", "cup", "plate", "pitcher")


def _floor(points: np.ndarray, centre: np.ndarray, table_z: float) -> float:
    """Lowest surface height above the table within 2 cm of ``centre`` (NaN if none)."""
    near = np.linalg.norm(points[:, :2] - centre, axis=1) <= 0.02
    return float(np.nanmin(points[near, 2]) - table_z) if np.any(near) else float("nan")


def main() -> None:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()  # --help describes, not runs
    print("| asset | rim (cm) | floor seen by the camera (cm) | floor in physics (cm) | rays low, shipped hulls "
          "| rays low, loaded |\n|---|---:|---:|---:|---:|---:|")
    for asset_id, asset in sorted(object_catalog().items()):
        if asset.name not in VESSELS:
            continue
        with SimEnv() as env:
            env.reset(SceneSpec("contain", asset_id, ("apple",), 0))
            obs = env.capture()
            body, table_z = env.scene.target.body_id, env.scene.layout.table_z
            assert obs.seg is not None
            seen = obs.points_world()[obs.seg == body]  # [m, 3]
            rays = top_surface_points(env.scene, body, 0.004)  # [n, 3]
            centre = rays[:, :2].mean(axis=0)

            print(f"| {asset_id} | {100 * (rays[:, 2].max() - table_z):.1f} | "
                  f"{100 * _floor(seen, centre, table_z):.1f} | {100 * _floor(rays, centre, table_z):.1f} | "
                  f"{rays_reaching_low(asset, False)} | {rays_reaching_low(asset, True)} |")


if __name__ == "__main__":
    main()
