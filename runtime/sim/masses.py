"""Masses for the assets whose URDF states none.

Every YCB URDF in ``shared/assets`` carries the same template inertia (``ixx="1e-3"``, which
pybullet does not use: it computes the inertia from the collision shape) and a mass of its own,
from 0.0052 kg (the dice) to 1.435 kg (the peg test). One asset's mass is the round ``0.001``,
below every other, read here as the converter's "no mass": ``a_marbles``, a 9 × 8 × 7 cm heap of 178 cm³
(its collision hulls). pybullet takes the gram literally, and the fingers' first contacts bat
such a body away: alone on the table it was missed in 3 of 3 poses, "fingers closed on nothing"
(``craft eval pickability --asset a_marbles``), while the same body at 50 g or 200 g was picked
in 3 of 3 (ad hoc, the mass set after loading). Glass marbles filling that volume would weigh a
few hundred grams.

The rule, from the catalogue alone: a stated mass at the placeholder (or none) is unknown, and
the body gets its collision volume times the catalogue's median density (stated mass over hull
volume, over every asset with a stated mass: ~0.74 g/cm³), ~131 g for the marbles. Every other
stated mass is used as written, light ones included. The 17 OCRTOC assets all state 0.1 kg, a
uniform value but a plausible one for their sizes (markers, cups, bowls, a stapler), so they
count; over the YCB assets alone the median is ~0.53 g/cm³ (~94 g): both lie inside the 50-200 g
that the ad hoc runs picked.

This is the simulator's physics, like the finer collision meshes (``collision_meshes.py``):
nothing here reaches perception, grounding or the grasp checks.
"""

from __future__ import annotations

import statistics
from functools import cache

from .assets import ObjectAsset, object_catalog
from .collision_meshes import hulls_volume, shipped_parts, urdf_link

PLACEHOLDER_MASS_KG = 0.001


class AssetMassError(ValueError):
    """An asset URDF whose ``<inertial><mass>`` value is not a number (a missing one is unknown)."""


@cache
def stated_mass(asset: ObjectAsset) -> float:
    """The mass (kg) the asset's URDF states for its one link."""
    _, link = urdf_link(asset)
    mass = link.find("inertial/mass")
    value = None if mass is None else mass.get("value")
    try:
        return float(value) if value is not None else float("nan")
    except ValueError:
        raise AssetMassError(
            f"{asset.urdf_path}: <inertial><mass value={value!r}> is not a number; "
            "give the link's mass in kg"
        ) from None


def is_placeholder(mass: float) -> bool:
    """True for the converter's "no mass" value (or a missing one)."""
    return not mass > PLACEHOLDER_MASS_KG


@cache
def hull_volume(asset: ObjectAsset) -> float:
    """Volume (m³) of the convex parts pybullet collides through, at the asset's scale."""
    return hulls_volume(shipped_parts(asset)) * asset.scale**3


@cache
def median_density() -> float:
    """Median of stated mass / hull volume (kg/m³) over the catalogue's assets with a mass."""
    densities = [
        stated_mass(a) / hull_volume(a)
        for a in object_catalog().values()
        if not is_placeholder(stated_mass(a)) and hull_volume(a) > 0.0
    ]
    return float(statistics.median(densities))


def sim_mass(asset: ObjectAsset) -> float | None:
    """The mass to give the body in place of its stated one, or None to keep the stated mass."""
    if not is_placeholder(stated_mass(asset)) or hull_volume(asset) <= 0.0:
        return None  # a body without volume keeps what it states rather than becoming static
    return hull_volume(asset) * median_density()
