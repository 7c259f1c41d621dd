"""The two grippers the simulated CR3 can carry, as data: links, joints, geometry, defaults.

``robotiq_2f85`` is the Robotiq 2F-85 from ``shared/assets/robots/robotiq_2f85``: 85 mm stroke,
22 x 37.5 mm pads on a four-bar linkage, the gripper closest to the paper's CR3 setup.
``panda`` is the Franka hand from ``pybullet_data`` (80 mm stroke, prismatic fingers).

The Franka hand stays the default because it picks better in this simulator, measured with the
same executor on the 105 dev episodes (``docs/results/sim_execution.md``): with the target's own
best grasp it picks 88 targets against the Robotiq model's 74, and CRAFT-E's Grasp Rate is 73.3
against 62.9. The Robotiq loses more grips on lifting and in transport, and its longer open
fingers leave more targets without a usable grasp. ``--gripper robotiq_2f85`` selects it.

Both hands close along their base link's y axis and approach along its z axis, so the arm's
top-down IK and the grasp geometry are shared. Each hand's TCP is placed so that the finger tips
end ``FINGERTIP_BELOW_TCP`` below it when the fingers close on a thin object; the executor keeps
the TCP that high above the table, so the tips never dig into it.

Measured on the Robotiq model in pybullet (``finger_joint`` 0 → 0.8 rad): the pad gap goes from
86.0 mm to 1.5 mm (3.4 mm since ``gripper.py`` servos the linkage rigid: the pads' tips meet
first) and the pad tips move 14 mm further from the base (149 → 163 mm), as the real linkage
does; hence the TCP is defined at the closed tips.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, get_args

from .clearance import HandBox
from .fingers import FingerGeometry

HandName = Literal["robotiq_2f85", "panda"]
HAND_NAMES: tuple[str, ...] = get_args(HandName)
DEFAULT_HAND: HandName = "panda"

# How far the finger tips reach below the TCP along the approach axis when closed; the executor
# keeps the TCP at least this high (plus a clearance) above the table. Shared by both hands: each
# hand's TCP offset is chosen to make it so.
FINGERTIP_BELOW_TCP = 0.0136


@dataclass(frozen=True)
class Mimic:
    """A joint that follows a driven joint: ``q = multiplier * q_driver`` (URDF ``mimic``)."""

    joint: str
    driver: str
    multiplier: float


@dataclass(frozen=True)
class HandSpec:
    """Everything the composer, the gripper driver and the checks need to know about a hand."""

    name: HandName
    base_link: str  # the link bolted to the CR3 flange
    driven_joints: tuple[str, ...]  # commanded directly (position control), one per finger
    mimics: tuple[Mimic, ...]  # coupled to a driven joint by gear constraints
    left_links: tuple[str, ...]  # links whose contacts count as the left finger's
    right_links: tuple[str, ...]
    left_pad: str  # link whose origin lies on the left pad (width measurement)
    right_pad: str
    pad_thickness: float  # m subtracted from the pad-origin distance to get the inner gap
    open_q: float  # driven joint value when fully open
    closed_q: float  # driven joint target when closing (its limit)
    stroke: float  # m, full opening
    tcp_offset: float  # m from the base link origin to the TCP along the approach axis
    force: float  # default motor effort (N per prismatic finger, N·m per linkage joint)
    max_speed: float  # m/s per prismatic finger or rad/s on the linkage's driven joint
    # The effort of a gentle grip (``ParallelGripper.close(gentle=True)``, for small objects:
    # ``PickConfig.gentle_below``), in ``force``'s unit; None: the hand has none (its squeeze is
    # not set by its effort, as the Robotiq's is not: ``GripperConfig``).
    gentle_force: float | None = None
    pad_lateral_friction: float = 1.5  # rubber-like; pybullet multiplies with the object's
    # Torsional friction about the contact normal, i.e. about the pinch axis: what keeps a long
    # object pinched off-centre from swinging down. pybullet multiplies it with the object's
    # spinning friction (``SurfaceModel``, 0.002 m), giving 0.006 m, a ~1 cm pad contact patch.
    pad_spinning_friction: float = 3.0
    pad_rolling_friction: float = 0.0
    # The open hand in the TCP frame for the depth clearance check (``clearance.py``); measured
    # from the model's link boxes, re-measured by ``tests/test_clearance.py``.
    clearance_boxes: tuple[HandBox, ...] = ()
    # The open hand seen from above, for the finger check and grasp refinement (``fingers.py``):
    # what fits between these pads is what this hand can close on.
    fingers: FingerGeometry = field(default_factory=FingerGeometry)


ROBOTIQ_2F85 = HandSpec(
    name="robotiq_2f85",
    base_link="robotiq_arg2f_base_link",
    # Upstream, right_outer_knuckle_joint mimics finger_joint. Driving it with its own motor
    # instead makes the fingers symmetric: through a gear constraint the right pad pressed with
    # 40% of the left's force on a fixed box (9.5 vs 24.4 N), so grasps were pushed sideways.
    driven_joints=("finger_joint", "right_outer_knuckle_joint"),
    mimics=(
        Mimic("left_inner_knuckle_joint", "finger_joint", 1.0),
        Mimic("left_inner_finger_joint", "finger_joint", -1.0),
        Mimic("right_inner_knuckle_joint", "right_outer_knuckle_joint", 1.0),
        Mimic("right_inner_finger_joint", "right_outer_knuckle_joint", -1.0),
    ),
    left_links=("left_inner_finger", "left_inner_finger_pad"),
    right_links=("right_inner_finger", "right_inner_finger_pad"),
    left_pad="left_inner_finger_pad",
    right_pad="right_inner_finger_pad",
    pad_thickness=0.00635,
    open_q=0.0,
    closed_q=0.8,
    stroke=0.085,
    # closed tips at 0.1632 m from the base (measured); TCP FINGERTIP_BELOW_TCP above them
    tcp_offset=0.1496,
    force=8.0,  # N·m per driven joint; see GripperConfig for the measured pad force
    max_speed=2.0,  # rad/s (the URDF limit): full close in ~0.45 s (the real one: ~0.6 s)
    clearance_boxes=(
        HandBox(0.041, -0.045, 0.045, 0.057, 0.155),  # base
        HandBox(0.022, 0.005, 0.058, 0.037, 0.096, mirrored=True),  # inner knuckles, over the object
        HandBox(0.016, 0.042, 0.076, 0.001, 0.107, mirrored=True),  # fingers and pads
    ),
    # 85 mm stroke (pads 42.5 mm from the centre when open); pads 22 mm wide (the URDF's pad box);
    # the finger's footprint is the "fingers and pads" box above (out to 7.6 cm, 3.2 cm wide)
    fingers=FingerGeometry(half_opening=0.0425, pad_half_width=0.011, finger_half_width=0.016,
                           finger_depth=0.0335),
)

PANDA = HandSpec(
    name="panda",
    base_link="panda_hand",
    driven_joints=("panda_finger_joint1", "panda_finger_joint2"),
    mimics=(),
    left_links=("panda_leftfinger",),
    right_links=("panda_rightfinger",),
    left_pad="panda_leftfinger",
    right_pad="panda_rightfinger",
    pad_thickness=0.0,
    open_q=0.04,
    closed_q=0.0,
    stroke=0.08,
    # The Franka grasp target sits at 0.105 m; the finger tips at 0.117 m down the hand.
    tcp_offset=0.1034,
    force=40.0,  # N per finger; above the rated 20 N so heavy bottles do not slip
    max_speed=0.2,
    # 20 N on objects under 15 cm: at 40 N pybullet squeezed the 6 g sponge out from between
    # the pads by its rounded ends (not a real sponge's behaviour: at 50 g, or at 20 N, the
    # same grasps hold); at 20 N for every object, plates and lids held by the rim and a tall
    # bottle were lost (docs/results/sim_execution.md, "A gentle grip on small objects")
    gentle_force=20.0,
    clearance_boxes=(
        HandBox(0.036, -0.106, 0.106, 0.033, 0.133),  # the hand's body, 21 cm along the closing axis
        HandBox(0.014, 0.036, 0.070, -0.013, 0.049, mirrored=True),  # open fingers
    ),
)

HANDS: dict[str, HandSpec] = {h.name: h for h in (ROBOTIQ_2F85, PANDA)}


def hand_spec(name: str) -> HandSpec:
    """The spec of ``name``, or a ValueError listing the choices."""
    try:
        return HANDS[name]
    except KeyError:
        raise ValueError(f"gripper {name!r}: choose one of {', '.join(HAND_NAMES)}") from None
