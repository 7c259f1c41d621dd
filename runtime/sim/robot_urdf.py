"""Build the loadable CR3 + Panda-hand URDF from the unmodified upstream files.

The Dobot CR3 URDF in ``shared/`` is read-only and, as shipped, wrong for pybullet: meshes point at
``package://dobot_rviz/...``, every joint has effort/velocity 0 (motors would exert no force), and
all materials are named ``""`` (pybullet caches materials by name, so the arm renders black). We fix
those in memory, attach the Franka hand from ``pybullet_data`` (a reliable parallel gripper without
mimic-joint constraints) to ``Link6``, add a ``tcp`` link between the finger tips, and write the
result into a cache folder keyed by the content hash of the inputs, so shared/ is never touched and
concurrent processes never see a half-written file.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import pybullet_data

from .assets import shared_path

CR3_DIR = "assets/robots/dobot_cr3"
CR3_URDF = f"{CR3_DIR}/cr3_robot.urdf"
PANDA_URDF = Path(pybullet_data.getDataPath()) / "franka_panda" / "panda.urdf"
BUILDER_VERSION = "cr3-panda-hand/v1"

JOINT_EFFORT = 150.0  # N·m; upstream says 0, which pybullet reads as "no motor force"
JOINT_VELOCITY = 3.14  # rad/s
FLANGE_LINK = "Link6"
HAND_LINKS = ("panda_hand", "panda_leftfinger", "panda_rightfinger")
FINGER_JOINTS = ("panda_finger_joint1", "panda_finger_joint2")
TCP_LINK = "tcp"
HAND_JOINT = "flange_to_hand"  # fixed joint whose child link is the hand
TCP_JOINT = "hand_to_tcp"
# Distance from the hand base to the point between the finger pads, along the approach axis.
# The Franka grasp target sits at 0.105 m; the pad centres are ~0.1 m down the hand.
TCP_OFFSET = 0.1034
# How far the finger tips reach below the TCP (finger collision mesh, measured: tips at 0.117 m
# down the hand). The executor keeps the TCP at least this high above the table.
FINGERTIP_BELOW_TCP = 0.0136
FINGER_FRICTION = 1.5  # rubber-like pads; pybullet multiplies this with the object's friction


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


def _hand_elements(panda_root: ET.Element, panda_dir: Path) -> list[ET.Element]:
    """The Franka hand links and finger joints, with absolute meshes and unique materials."""
    keep: list[ET.Element] = []
    for link in panda_root.findall("link"):
        if link.attrib["name"] in HAND_LINKS:
            keep.append(link)
    for joint in panda_root.findall("joint"):
        if joint.attrib["name"] in FINGER_JOINTS:
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
            friction.attrib["value"] = f"{FINGER_FRICTION}"
    return keep


def _fixed_joint(name: str, parent: str, child: str, xyz: str, rpy: str = "0 0 0") -> ET.Element:
    joint = ET.Element("joint", name=name, type="fixed")
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    ET.SubElement(joint, "origin", xyz=xyz, rpy=rpy)
    return joint


def _inertial(mass: float) -> ET.Element:
    inertial = ET.Element("inertial")
    ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=f"{mass}")
    ET.SubElement(
        inertial, "inertia", ixx="1e-6", ixy="0", ixz="0", iyy="1e-6", iyz="0", izz="1e-6"
    )
    return inertial


def _tcp_link() -> ET.Element:
    """A tiny near-massless link so getLinkState/IK can address the grasp point directly."""
    link = ET.Element("link", name=TCP_LINK)
    link.append(_inertial(0.001))
    return link


def compose_urdf_text() -> str:
    """The fixed CR3 with the Franka hand on its flange, as URDF text."""
    cr3_urdf = shared_path(CR3_URDF)
    cr3_root = ET.parse(cr3_urdf).getroot()
    _fix_cr3(cr3_root, shared_path(f"{CR3_DIR}/meshes"))
    panda_root = ET.parse(PANDA_URDF).getroot()
    cr3_root.extend(_hand_elements(panda_root, PANDA_URDF.parent))
    cr3_root.append(_fixed_joint(HAND_JOINT, FLANGE_LINK, "panda_hand", "0 0 0"))
    cr3_root.append(_tcp_link())
    cr3_root.append(_fixed_joint(TCP_JOINT, "panda_hand", TCP_LINK, f"0 0 {TCP_OFFSET}"))
    ET.indent(cr3_root)
    return ET.tostring(cr3_root, encoding="unicode")


def _cache_dir() -> Path:
    base = os.environ.get("CRAFT_SIM_CACHE") or os.path.join(tempfile.gettempdir(), "craft_e_sim")
    return Path(base)


def robot_urdf_path() -> Path:
    """Path of the composed URDF, (re)built when its inputs or this builder change."""
    text = compose_urdf_text()
    digest = hashlib.sha256(f"{BUILDER_VERSION}\n{text}".encode()).hexdigest()[:16]
    path = _cache_dir() / f"cr3_panda_{digest}.urdf"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".urdf.tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(tmp, path)  # atomic: a concurrent reader sees the old or the whole new file
    return path
