"""The DeepMimic humanoid (15 bodies, 45 kg, ~1.62 m): the skeleton of the DeepMimic clips.

Read from `common/data/mocap/deepmimic/characters/humanoid3d.txt` (DeepMimic's JSON). Body,
joint and geom names are DeepMimic's joint names (`root`, `chest`, `neck`, `right_hip`, ...),
each body carrying the shape DeepMimic attaches to that joint; wrists are jointless bodies.

Frames: DeepMimic is Y up, X forward; MuJoCo here is Z up, X forward: a vector (x, y, z) maps to
(x, -z, y) and a quaternion (w, x, y, z) to (w, x, -z, y) (`DEEPMIMIC_TO_MUJOCO`); every body
frame is parallel to the world at the rest pose, so a clip's local joint quaternion, mapped
that way, is the ball joint's `qpos`. Knees and elbows turn about (0, -1, 0) with DeepMimic's
angle. qpos order is MuJoCo's depth-first body order, not DeepMimic's joint order: look joints
up by name (`Character.qpos_slices`); `DEEPMIMIC_JOINT_ORDER` lists the clip order.
PD gains are DeepMimic's humanoid3d controller gains; torque limits its `TorqueLim`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from common.characters import builder
from common.characters.builder import BaseCharacter, GeomDef, JointDef
from common.characters.shape_space import BodyPart, ShapeParam, ShapeSpace, random_space, uniform_space

DATA_FILE = Path(__file__).resolve().parents[2] / "data" / "mocap" / "deepmimic" / "characters" / "humanoid3d.txt"
DEEPMIMIC_TO_MUJOCO = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
DEEPMIMIC_JOINT_ORDER = (
    "chest", "neck", "right_hip", "right_knee", "right_ankle", "right_shoulder", "right_elbow",
    "left_hip", "left_knee", "left_ankle", "left_shoulder", "left_elbow",
)
# DeepMimic humanoid3d_ctrl.txt gains (kp [N m/rad], kd [N m s/rad]).
GAINS = {
    "chest": (1000.0, 100.0), "neck": (100.0, 10.0), "hip": (500.0, 50.0), "knee": (500.0, 50.0),
    "ankle": (400.0, 40.0), "shoulder": (400.0, 40.0), "elbow": (300.0, 30.0),
}
GROUPS = {
    "root": ("lower", "trunk"), "chest": ("upper", "trunk"), "neck": ("upper", "head"),
    "hip": ("lower", "leg"), "knee": ("lower", "leg"), "ankle": ("lower", "foot"),
    "shoulder": ("upper", "arm"), "elbow": ("upper", "arm"), "wrist": ("upper", "hand"),
}


def _vec(x: float, y: float, z: float) -> np.ndarray:
    return DEEPMIMIC_TO_MUJOCO @ np.array([x, y, z], dtype=float)


def _geom(shape: dict) -> GeomDef:
    pos = _vec(shape["AttachX"], shape["AttachY"], shape["AttachZ"])
    p0, p1, p2 = shape["Param0"], shape["Param1"], shape["Param2"]
    kind = shape["Shape"]
    if kind == "sphere":
        size: tuple[float, ...] = (p0 / 2.0,)
    elif kind == "capsule":  # DeepMimic: diameter, cylinder length along its Y (our z)
        size = (p0 / 2.0, p1 / 2.0)
    elif kind == "box":  # full extents along DeepMimic x, y, z -> half-sizes along our x, y, z
        size = (p0 / 2.0, p2 / 2.0, p1 / 2.0)
    else:
        raise ValueError(f"humanoid3d.txt: unsupported shape {kind!r}")
    return GeomDef(kind, size, float(shape["Mass"]), tuple(pos))


def _joint(j: dict) -> JointDef | None:
    kind = j["Type"]
    part = j["Name"].split("_")[-1]
    if kind == "spherical":
        kp, kd = GAINS[part]
        lo = [j["LimLow0"], j["LimLow1"], j["LimLow2"]]
        hi = [j["LimHigh0"], j["LimHigh1"], j["LimHigh2"]]
        # DeepMimic axis k -> our axes: x <- x, y <- -z, z <- y.
        ranges = ((lo[0], hi[0]), (-hi[2], -lo[2]), (lo[1], hi[1]))
        return JointDef(j["Name"], "ball", kp, kd, float(j["TorqueLim"]), ranges)
    if kind == "revolute":
        kp, kd = GAINS[part]
        return JointDef(j["Name"], "hinge", kp, kd, float(j["TorqueLim"]), ((j["LimLow0"], j["LimHigh0"]),),
                        axis=(0.0, -1.0, 0.0))
    return None


def build(timestep_s: float) -> BaseCharacter:
    """The DeepMimic humanoid as a MuJoCo spec with PD actuators (see builder.py)."""
    data = json.loads(DATA_FILE.read_text())
    joints = data["Skeleton"]["Joints"]
    shapes = {b["ID"]: b for b in data["BodyDefs"]}
    spec = builder.new_world("humanoid", timestep_s, swimmer=False)
    bodies = {}
    actuated: list[JointDef] = []
    parts = []
    # NOTE: MuJoCo numbers bodies depth first, so add children in tree order under each parent.
    def add(jid: int, parent_body) -> None:
        j = joints[jid]
        jd = _joint(j)
        pos = _vec(j["AttachX"], j["AttachY"], j["AttachZ"])
        body = builder.add_body(parent_body, j["Name"], pos if j["Parent"] >= 0 else (0.0, 0.0, 0.9),
                                [_geom(shapes[jid])], [jd] if jd else [], free=j["Parent"] < 0)
        bodies[j["Name"]] = body
        if jd:
            actuated.append(jd)
        side = ("_left",) if j["Name"].startswith("left") else ("_right",) if j["Name"].startswith("right") else ("",)
        groups = GROUPS[j["Name"].split("_")[-1]]
        groups = groups + tuple(g + side[0] for g in groups if side[0])
        parts.append(BodyPart(j["Name"], groups, long_axis=0 if "ankle" in j["Name"] else 2))
        for child in joints:
            if child["Parent"] == jid:
                add(child["ID"], body)

    add(0, spec.worldbody)
    builder.add_pd_actuators(spec, actuated)
    builder.add_tracking_camera(bodies["root"], 3.0, 0.5)
    parts_t = tuple(parts)
    spaces = {s.name: s for s in (random_space(parts_t), uniform_space(), *biped_spaces(("arm",)))}
    return BaseCharacter(
        preset="humanoid", spec=spec, parts=parts_t, spaces=spaces,
        foot_geoms=("right_ankle", "left_ankle"),
        legs=(("right_hip", "right_ankle"), ("left_hip", "left_ankle")),
        end_effector_bodies=("right_ankle", "left_ankle", "right_wrist", "left_wrist"),
        root_body="root",
        extras={"deepmimic_joint_order": DEEPMIMIC_JOINT_ORDER},
    )


def biped_spaces(arm_groups: tuple[str, ...] | None) -> list[ShapeSpace]:
    """Won & Lee 2019 parameterizations for bipeds (group tags as in GROUPS); leave out
    leg_arm when arm_groups is None (the lower-body biped)."""
    spaces = []
    if arm_groups is not None:
        spaces.append(ShapeSpace("leg_arm", (
            ShapeParam("leg_length", 0.5, 2.0, ("leg",), "long", "length of thighs and shanks"),
            ShapeParam("arm_length", 0.5, 1.5, arm_groups, "long", "length of upper arms and forearms"),
        ), "leg length x0.5..x2.0 vs arm length x0.5..x1.5"))
    spaces.append(ShapeSpace("left_right_leg", (
        ShapeParam("left_leg", 0.9, 1.1, ("leg_left",), "long", "length of the left thigh and shank"),
        ShapeParam("right_leg", 0.9, 1.1, ("leg_right",), "long", "length of the right thigh and shank"),
    ), "left vs right leg length, each +-10%"))
    spaces.append(ShapeSpace("height_thickness", (
        ShapeParam("height", 0.75, 1.5, ("*",), "long", "length of every segment along its bone"),
        ShapeParam("thickness", 0.5, 1.5, ("*",), "thick", "cross-section of every segment"),
    ), "height x0.75..x1.5 vs thickness x0.5..x1.5"))
    spaces.append(ShapeSpace("upper_lower_thickness", (
        ShapeParam("upper_thickness", 0.5, 1.5, ("upper",), "thick", "cross-section of trunk above the pelvis, head, arms"),
        ShapeParam("lower_thickness", 0.5, 1.5, ("lower",), "thick", "cross-section of pelvis, legs and feet"),
    ), "upper vs lower body thickness, x0.5..x1.5 each"))
    return spaces
