"""The open hand seen from above, and whether an object's section fits between its fingers.

Shared by the grasp checks of the evaluation's and the robot's paths (``grasp_checks``,
``candidates``, ``choose``) and by grasp refinement (``refine``), which proposes grasps and must
check them the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..grasp.geometry import TopDownGrasp

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class FingerGeometry:
    """The open hand seen from above (defaults: the Franka hand; ``HandSpec.fingers`` has each
    hand's; the executor always opens the hand fully)."""

    half_opening: float = 0.04  # m from the grasp centre to each pad's inner face
    # m wanted between each pad and the object as the fingers descend. 3 mm (was 2): at 2 mm,
    # grasps on sections seen at 7.2-7.6 cm passed and five dev targets rode to the zone pinched
    # between the fully open fingers and stayed there; at 3 mm three sim-val ones (shampoo,
    # gelatin box, sponge) executed another grasp and succeeded (sim-val CRAFT-E 237 -> 240 of
    # 378, sim-dev 81 -> 81; docs/results/sim_execution.md)
    clearance: float = 0.003
    thickness: float = 0.012  # m of finger along the closing axis: a narrower gap takes no finger
    pad_half_width: float = 0.01  # m of pad across the closing axis, each side of the axis
    height_tolerance: float = 0.003  # m: surfaces this close to the finger tips are not squeezed
    min_points: int = 4  # pixels, so single noisy depth pixels do not count as an object
    # Reject a grasp whose finger would come down on the object's own surface beside the
    # opening (a mug's far rim or handle): the finger stops on it and the hand never reaches the
    # grasp. Off reproduces the checks before this rule (tests/test_finger_checks_fast.py).
    check_landing: bool = True
    # The open finger's footprint, from the hand model's "open fingers" box (hands.PANDA's
    # clearance boxes: 3.6-7.0 cm from the centre, 2.8 cm wide)
    finger_half_width: float = 0.014  # m across the closing axis, each side
    finger_depth: float = 0.030  # m along the closing axis, outwards from the pad's inner face

    @property
    def max_span(self) -> float:
        return 2 * (self.half_opening - self.clearance)


class SurfacePoints:
    """An object's surface points and the per-centre work of finger checks, done once.

    Grasp refinement checks up to ~20 grasps on one ROI, most of them turns about one centre,
    and its wall search projects the same points again; a one-off ``finger_check`` gathered the
    points' x, y relative to the centre through a two-wide strided array (~0.5 ms on a 25k-point
    ROI, most of a check). Here those offsets, the strips and the height masks are kept per
    centre, axis and height. Every value is computed by the same numpy operation on the same
    numbers as the one-off check did (the offsets' rows, ``@`` on a C-ordered ``[m, 2]`` array,
    the same sort), so every answer is bit-for-bit the same.
    """

    def __init__(self, material: FloatArray) -> None:
        self.material = material  # [m, 3] world
        self.z = np.ascontiguousarray(material[:, 2])  # [m]
        # keyed by the exact bits of centres and axes: 0.0 and -0.0 are one float key, but
        # x - 0.0 and x - -0.0 differ in the sign of a zero
        self._rel: dict[bytes, FloatArray] = {}
        self._strip: dict[tuple[bytes, bytes, float], BoolArray] = {}
        self._above: dict[float, BoolArray] = {}

    def rel(self, centre_xy: FloatArray) -> FloatArray:
        """``material[:, :2] - centre_xy`` ``[m, 2]`` (C order; ``centre_xy`` float64 ``[2]``),
        one column at a time: ~10x faster than through the two-wide strided slice."""
        key = centre_xy.tobytes()
        if key not in self._rel:
            out = np.empty((len(self.material), 2), dtype=np.float64)
            np.subtract(self.material[:, 0], centre_xy[0], out=out[:, 0])
            np.subtract(self.material[:, 1], centre_xy[1], out=out[:, 1])
            self._rel[key] = out
        return self._rel[key]

    def strip(self, centre_xy: FloatArray, normal: FloatArray, half_width: float) -> BoolArray:
        """``[m]`` points within ``half_width`` of the line through ``centre_xy`` across ``normal``."""
        key = (centre_xy.tobytes(), normal.tobytes(), half_width)
        if key not in self._strip:
            self._strip[key] = np.abs(self.rel(centre_xy) @ normal) <= half_width
        return self._strip[key]

    def above(self, z: float) -> BoolArray:
        """``[m]`` points higher than ``z``."""
        if z not in self._above:
            self._above[z] = self.z > z
        return self._above[z]

    def along(self, centre_xy: FloatArray, chosen: BoolArray, axis: FloatArray) -> FloatArray:
        """``[k]`` the ``chosen`` points' coordinates along ``axis`` from ``centre_xy``, in order."""
        return self.rel(centre_xy).take(np.flatnonzero(chosen), axis=0) @ axis


def surface_of(material: FloatArray | SurfacePoints) -> SurfacePoints:
    """``material`` as ``SurfacePoints`` (a new one for a bare ``[m, 3]`` array): callers that
    check many grasps on one ROI pass one ``SurfacePoints`` so that they share its work."""
    return material if isinstance(material, SurfacePoints) else SurfacePoints(material)


def finger_check(
    material: FloatArray | SurfacePoints, pose: TopDownGrasp, tip_z: float, fingers: FingerGeometry
) -> tuple[bool, str]:
    """Does the object fit between the open fingers at their height? (ok, why not)

    ``material`` ``[m, 3]`` are the object's surface points (its ROI's depth pixels in the
    world), bare or as ``SurfacePoints`` shared between checks. Only surface above the finger
    tips ``tip_z`` is squeezed, so one finger may go inside a cup for a rim grasp. Points within
    a pad-wide strip along the closing axis are projected on it and split into runs where a gap is
    wide enough for a finger; the runs that reach between the open pads are what the fingers
    close on. The grasp fits if their total span leaves the clearance on both sides. The span, not
    the centring, decides: the two fingers close symmetrically and push an off-centre object to
    the middle. Then no surface above the tips may lie under an open finger's footprint
    (``check_landing``): the finger would come down on it and stop short of the grasp.

    The span rule was checked against physics on label-free random scenes at 2 mm clearance
    (GR-ConvNet's top-3 grasps of 70 targets, 115 picks): 85% of the grasps it kept succeeded, against 27% of those
    it rejected, and it kept 87% of the grasps that succeeded.
    """
    surface = surface_of(material)
    axis = np.array([np.cos(pose.yaw), np.sin(pose.yaw)])
    normal = np.array([-axis[1], axis[0]])
    centre = np.asarray(pose.position[:2], dtype=np.float64)
    squeezed = surface.strip(centre, normal, fingers.pad_half_width) & surface.above(
        tip_z + fingers.height_tolerance)
    along = np.sort(surface.along(centre, squeezed, axis))  # [k]
    if along.size < fingers.min_points:
        return False, "no object surface between the fingers at their height"
    breaks = np.nonzero(np.diff(along) > fingers.thickness)[0]
    lows = along[np.concatenate([[0], breaks + 1])]
    highs = along[np.concatenate([breaks, [len(along) - 1]])]
    between = (highs > -fingers.half_opening) & (lows < fingers.half_opening)  # runs the pads meet
    if not np.any(between):
        return False, "no object surface between the fingers at their height"
    span = float(highs[between].max() - lows[between].min())
    if span > fingers.max_span:
        return False, (f"object section {span * 100:.1f} cm does not fit the "
                       f"{fingers.max_span * 100:.1f} cm opening")
    if fingers.check_landing:
        beside = surface.strip(centre, normal, fingers.finger_half_width) & surface.above(
            tip_z + fingers.height_tolerance)
        outside = np.abs(surface.along(centre, beside, axis)) - fingers.half_opening  # [k] beyond a pad
        under = np.count_nonzero((outside >= 0.0) & (outside <= fingers.finger_depth))
        if under >= fingers.min_points:
            return False, "a finger would land on the object beside the opening"
    return True, ""
