"""The paper's full biped: the MASS skeleton (19 box segments, ~1.70 m, ~60 kg without toes).

Read from `common/data/models/mass_human/human.xml` (DART-style XML, not MJCF), leaving out its
four toe bodies. Body and joint names are MASS's node names (`Pelvis`, `FemurR`, `TibiaR`,
`TalusR`, `Spine`, `Torso`, `Neck`, `Head`, `ShoulderR`, `ArmR`, `ForeArmR`, `HandR`, ... L);
`MASS_BVH_JOINTS` maps each to the BVH joint that drives it.

Frames: MASS is Y up and faces +Z with the character's left on +X; MuJoCo here is Z up facing
+X with the left on +Y: a MASS vector (x, y, z) maps to (z, x, y) (`MASS_TO_MUJOCO`, a proper
rotation). Every MASS joint frame is parallel to the world at the rest (T) pose and so is every
body frame here, so a BVH local rotation R (in MASS axes) becomes the ball joint's quaternion
of MASS_TO_MUJOCO @ R @ MASS_TO_MUJOCO.T. Knees turn about +Y (MASS +X), elbows about +Z
(MASS +Y), with MASS's angles. PD gains and torque limits are not in the file; they follow
the DeepMimic humanoid's per joint kind (GAINS).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common.characters import builder
from common.characters.builder import BaseCharacter, GeomDef, JointDef
from common.characters.presets.humanoid import biped_spaces
from common.characters.shape_space import BodyPart, random_space, uniform_space

DATA_FILE = Path(__file__).resolve().parents[2] / "data" / "models" / "mass_human" / "human.xml"
MASS_TO_MUJOCO = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
TOES = ("FootThumbR", "FootPinkyR", "FootThumbL", "FootPinkyL")
# kind -> (kp [N m/rad], kd [N m s/rad], torque limit [N m]), modelled on DeepMimic's humanoid.
GAINS = {
    "Pelvis": None, "Femur": (500.0, 50.0, 200.0), "Tibia": (500.0, 50.0, 150.0), "Talus": (400.0, 40.0, 90.0),
    "Spine": (1000.0, 100.0, 200.0), "Torso": (1000.0, 100.0, 200.0), "Neck": (100.0, 10.0, 50.0),
    "Head": (100.0, 10.0, 50.0), "Shoulder": (400.0, 40.0, 100.0), "Arm": (400.0, 40.0, 100.0),
    "ForeArm": (300.0, 30.0, 60.0), "Hand": (100.0, 10.0, 30.0),
}
GROUPS = {
    "Pelvis": ("lower", "trunk"), "Femur": ("lower", "leg"), "Tibia": ("lower", "leg"), "Talus": ("lower", "foot"),
    "Spine": ("upper", "trunk"), "Torso": ("upper", "trunk"), "Neck": ("upper", "head"), "Head": ("upper", "head"),
    "Shoulder": ("upper", "clavicle"), "Arm": ("upper", "arm"), "ForeArm": ("upper", "arm"), "Hand": ("upper", "hand"),
}
LONG_AXIS = {"Talus": 0, "Shoulder": 1, "Arm": 1, "ForeArm": 1, "Hand": 1}  # default 2 (vertical)


@dataclass(frozen=True)
class MassNode:
    """One MASS node in MuJoCo axes: box half-sizes [3], box rotation [3, 3] and centre [3]
    (world, rest pose), joint type/anchor [3]/axis [3]/limits."""

    name: str
    parent: str | None
    mass_kg: float
    half_size: np.ndarray
    box_rot: np.ndarray
    box_pos: np.ndarray
    joint_type: str
    joint_pos: np.ndarray
    axis: np.ndarray | None
    lower: np.ndarray
    upper: np.ndarray
    bvh: str | None


def _floats(text: str) -> np.ndarray:
    return np.array([float(v) for v in text.split()], dtype=float)


def parse_mass(path: Path = DATA_FILE) -> dict[str, MassNode]:
    """MASS nodes by name (toes included), converted to MuJoCo axes."""
    nodes = {}
    M = MASS_TO_MUJOCO
    for node in ET.parse(path).getroot().iter("Node"):
        body, joint = node.find("Body"), node.find("Joint")
        bt, jt = body.find("Transformation"), joint.find("Transformation")
        rot = _floats(bt.get("linear")).reshape(3, 3)  # row-major, as MASS reads it
        axis = joint.get("axis")
        nodes[node.get("name")] = MassNode(
            name=node.get("name"), parent=None if node.get("parent") == "None" else node.get("parent"),
            mass_kg=float(body.get("mass")),
            half_size=_floats(body.get("size")) / 2.0, box_rot=M @ rot, box_pos=M @ _floats(bt.get("translation")),
            joint_type=joint.get("type"), joint_pos=M @ _floats(jt.get("translation")),
            axis=None if axis is None else M @ _floats(axis),
            lower=_floats(joint.get("lower", "0 0 0")), upper=_floats(joint.get("upper", "0 0 0")),
            bvh=joint.get("bvh"),
        )
    return nodes


def _kind(name: str) -> str:
    return name[:-1] if name[-1] in "RL" and name not in ("Pelvis",) else name


def node_joint(n: MassNode, name: str | None = None) -> JointDef | None:
    """The PD joint of a MASS node (None for the free root)."""
    gains = GAINS[_kind(n.name)]
    if n.joint_type == "Free" or gains is None:
        return None
    kp, kd, tau = gains
    if n.joint_type == "Ball":
        # Per MuJoCo body axis the MASS axis it came from: x <- MASS z, y <- MASS x, z <- MASS y.
        ranges = tuple((n.lower[k], n.upper[k]) for k in (2, 0, 1))
        return JointDef(name or n.name, "ball", kp, kd, tau, ranges)
    return JointDef(name or n.name, "hinge", kp, kd, tau, ((n.lower[0], n.upper[0]),), axis=tuple(n.axis))


def node_geom(n: MassNode, joint_world: np.ndarray, name: str | None = None, mass_kg: float | None = None) -> GeomDef:
    """The node's box as a geom in a world-parallel body frame anchored at `joint_world`."""
    return GeomDef("box", tuple(n.half_size), n.mass_kg if mass_kg is None else mass_kg,
                   tuple(n.box_pos - joint_world), tuple(builder.quat_from_matrix(n.box_rot)), name)


def build_mass_tree(spec, nodes: dict[str, MassNode], keep: list[str], extra_geoms: dict | None = None):
    """Add the MASS nodes in `keep` (tree order) to `spec`; returns (bodies, joints, parts)."""
    extra_geoms = extra_geoms or {}
    bodies, joints, parts = {}, [], []

    def add(name: str, parent_body, parent_anchor: np.ndarray) -> None:
        n = nodes[name]
        jd = node_joint(n)
        free = n.parent is None
        pos = n.joint_pos - parent_anchor if not free else n.joint_pos
        geoms = [node_geom(n, n.joint_pos)] + [node_geom(nodes[e], n.joint_pos, name=e) for e in extra_geoms.get(name, ())]
        body = builder.add_body(parent_body, name, pos, geoms, [jd] if jd else [], free=free)
        bodies[name] = body
        if jd:
            joints.append(jd)
        kind = _kind(name)
        side = {"R": "_right", "L": "_left"}.get(name[-1], "") if kind != name else ""
        groups = GROUPS[kind] + tuple(g + side for g in GROUPS[kind] if side)
        parts.append(BodyPart(name, groups, LONG_AXIS.get(kind, 2)))
        for child in keep:
            if nodes[child].parent == name:
                add(child, body, n.joint_pos)

    add(keep[0], spec.worldbody, np.zeros(3))
    return bodies, joints, parts


MASS_BVH_JOINTS = {n.name: n.bvh for n in parse_mass().values() if n.bvh and n.name not in TOES}


def build(timestep_s: float) -> BaseCharacter:
    """The 19-segment MASS biped with PD actuators (see builder.py)."""
    nodes = parse_mass()
    keep = [k for k in nodes if k not in TOES]
    spec = builder.new_world("biped", timestep_s, swimmer=False)
    bodies, joints, parts = build_mass_tree(spec, nodes, keep)
    builder.add_pd_actuators(spec, joints)
    builder.add_tracking_camera(bodies["Pelvis"], 3.0, 0.5)
    parts_t = tuple(parts)
    spaces = {s.name: s for s in (random_space(parts_t), uniform_space(), *biped_spaces(("arm",)))}
    return BaseCharacter(
        preset="biped", spec=spec, parts=parts_t, spaces=spaces, foot_geoms=("TalusR", "TalusL"),
        legs=(("FemurR", "TalusR"), ("FemurL", "TalusL")),
        end_effector_bodies=("TalusR", "TalusL", "HandR", "HandL", "Head"), root_body="Pelvis",
        extras={"mass_bvh_joints": MASS_BVH_JOINTS, "mass_to_mujoco": MASS_TO_MUJOCO},
    )
