"""Build the loadable CR3 + gripper URDF from the unmodified upstream files.

The Dobot CR3 URDF in ``shared/`` is read-only and, as shipped, wrong for pybullet: meshes point at
``package://dobot_rviz/...``, every joint has effort/velocity 0 (motors would exert no force), and
all materials are named ``""`` (pybullet caches materials by name, so the arm renders black). We fix
those in memory, attach a hand (``hands.py``: the Franka hand from ``pybullet_data`` by default, or
the Robotiq 2F-85 from ``shared/``) to ``Link6``, add a ``tcp`` link between the finger pads,
and write the result into a cache folder keyed by the content hash of the inputs, so shared/ is
never touched and concurrent processes never see a half-written file.

The Robotiq URDF needs two more fixes: its meshes point at ``package://robotiq_2f_85_...``, and
its finger links have no ``<inertial>`` (commented out upstream), which pybullet replaces by
1 kg and unit inertia per link, a hand of 8 kg of wobbling fingers; we give them their upstream
masses. Its ``mimic`` tags are ignored by pybullet; the gripper adds gear constraints.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import pybullet_data

from .assets import shared_path
from .hands import (
    DEFAULT_HAND,
    FINGERTIP_BELOW_TCP,
    PANDA,
    HandSpec,
    hand_spec,
)

CR3_DIR = "assets/robots/dobot_cr3"
CR3_URDF = f"{CR3_DIR}/cr3_robot.urdf"
PANDA_URDF = Path(pybullet_data.getDataPath()) / "franka_panda" / "panda.urdf"
ROBOTIQ_URDF = "assets/robots/robotiq_2f85/robotiq_85.urdf"
BUILDER_VERSION = "cr3-hand/v2"

JOINT_EFFORT = 150.0  # N·m; upstream says 0, which pybullet reads as "no motor force"
JOINT_VELOCITY = 3.14  # rad/s
FLANGE_LINK = "Link6"
PANDA_HAND_LINKS = ("panda_hand", "panda_leftfinger", "panda_rightfinger")
TCP_LINK = "tcp"
HAND_JOINT = "flange_to_hand"  # fixed joint whose child link is the hand
TCP_JOINT = "hand_to_tcp"
# Upstream masses of the Robotiq links (kg), from the commented-out <inertial> blocks.
ROBOTIQ_LINK_MASS = {
    "outer_knuckle": 0.00853,
    "outer_finger": 0.02261,
    "inner_finger": 0.01040,
    "inner_finger_pad": 0.005,  # not given upstream: a 22 x 6 x 37 mm rubber pad
    "inner_knuckle": 0.02712,
}
__all__ = ["FINGERTIP_BELOW_TCP", "compose_urdf_text", "robot_urdf_path"]


def _fix_cr3(root: ET.Element, meshes_dir: Path) -> None:
    """Apply the three documented CR3 fixes in place."""
    for mesh in root.iter("mesh"):
        name = Path(mesh.attrib["filename"]).name
        mesh.attrib["filename"] = str(meshes_dir / name)
    for limit in root.iter("limit"):
        limit.attrib["effort"] = f"{JOINT_EFFORT}"
        limit.attrib["velocity"] = f"{JOINT_VELOCITY}"
    for link in root.iter("link"):
        for i, material in enumerate(link.iter("material")):
            material.attrib["name"] = f"cr3_{link.attrib['name']}_{i}"
        if link.find("inertial") is None:  # the fixed root "dummy_link": silences a loader warning
            link.append(_inertial(0.001))


def _panda_elements(panda_root: ET.Element, panda_dir: Path) -> list[ET.Element]:
    """The Franka hand links and finger joints, with absolute meshes and unique materials."""
    keep: list[ET.Element] = []
    for link in panda_root.findall("link"):
        if link.attrib["name"] in PANDA_HAND_LINKS:
            keep.append(link)
    for joint in panda_root.findall("joint"):
        if joint.attrib["name"] in PANDA.driven_joints:
            mimic = joint.find("mimic")
            if mimic is not None:  # pybullet ignores mimic tags; both fingers are commanded
                joint.remove(mimic)
            keep.append(joint)
    for element in keep:
        for mesh in element.iter("mesh"):
            rel = mesh.attrib["filename"].removeprefix("package://")
            mesh.attrib["filename"] = str(panda_dir / rel)
        for material in element.iter("material"):
            material.attrib["name"] = "panda_hand_white"
            if material.find("color") is None:
                ET.SubElement(material, "color", rgba="0.95 0.95 0.95 1")
        for friction in element.iter("lateral_friction"):
            friction.attrib["value"] = f"{PANDA.pad_lateral_friction}"
    return keep


def _robotiq_elements(root: ET.Element, meshes_dir: Path) -> list[ET.Element]:
    """The Robotiq 2F-85 links and joints: absolute meshes, unique materials, real masses.

    Mimic tags stay (documentation; pybullet ignores them). Link names are unique in the
    composed tree already (``robotiq_arg2f_*``, ``left_*``, ``right_*``).
    """
    keep = [*root.findall("link"), *root.findall("joint")]
    for element in keep:
        for mesh in element.iter("mesh"):
            rel = mesh.attrib["filename"].split("/meshes/", 1)[1]
            mesh.attrib["filename"] = str(meshes_dir / rel)
        for i, material in enumerate(element.iter("material")):
            material.attrib["name"] = f"robotiq_{element.attrib['name']}_{i}"
    for link in root.findall("link"):
        if link.find("inertial") is None:
            name = link.attrib["name"].removeprefix("left_").removeprefix("right_")
            link.append(_inertial(ROBOTIQ_LINK_MASS.get(name, 0.01), inertia=2e-6))
    return keep


def _hand_elements(hand: HandSpec) -> list[ET.Element]:
    if hand.name == "panda":
        panda_root = ET.parse(PANDA_URDF).getroot()
        return _panda_elements(panda_root, PANDA_URDF.parent)
    path = shared_path(ROBOTIQ_URDF)
    return _robotiq_elements(ET.parse(path).getroot(), path.parent / "meshes")


def _fixed_joint(name: str, parent: str, child: str, xyz: str, rpy: str = "0 0 0") -> ET.Element:
    joint = ET.Element("joint", name=name, type="fixed")
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    ET.SubElement(joint, "origin", xyz=xyz, rpy=rpy)
    return joint


def _inertial(mass: float, inertia: float = 1e-6) -> ET.Element:
    inertial = ET.Element("inertial")
    ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=f"{mass}")
    i = f"{inertia:g}"
    ET.SubElement(inertial, "inertia", ixx=i, ixy="0", ixz="0", iyy=i, iyz="0", izz=i)
    return inertial


def _tcp_link() -> ET.Element:
    """A tiny near-massless link so getLinkState/IK can address the grasp point directly."""
    link = ET.Element("link", name=TCP_LINK)
    link.append(_inertial(0.001))
    return link


def compose_urdf_text(hand: str = DEFAULT_HAND) -> str:
    """The fixed CR3 with ``hand`` on its flange, as URDF text."""
    spec = hand_spec(hand)
    cr3_urdf = shared_path(CR3_URDF)
    cr3_root = ET.parse(cr3_urdf).getroot()
    _fix_cr3(cr3_root, shared_path(f"{CR3_DIR}/meshes"))
    cr3_root.extend(_hand_elements(spec))
    cr3_root.append(_fixed_joint(HAND_JOINT, FLANGE_LINK, spec.base_link, "0 0 0"))
    cr3_root.append(_tcp_link())
    cr3_root.append(_fixed_joint(TCP_JOINT, spec.base_link, TCP_LINK, f"0 0 {spec.tcp_offset}"))
    ET.indent(cr3_root)
    return ET.tostring(cr3_root, encoding="unicode")


def _cache_dir() -> Path:
    base = os.environ.get("CRAFT_SIM_CACHE") or os.path.join(tempfile.gettempdir(), "craft_e_sim")
    return Path(base)


def robot_urdf_path(hand: str = DEFAULT_HAND) -> Path:
    """Path of the composed URDF, (re)built when its inputs or this builder change."""
    text = compose_urdf_text(hand)
    digest = hashlib.sha256(f"{BUILDER_VERSION}\n{text}".encode()).hexdigest()[:16]
    path = _cache_dir() / f"cr3_{hand}_{digest}.urdf"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".urdf.tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(tmp, path)  # atomic: a concurrent reader sees the old or the whole new file
    return path
