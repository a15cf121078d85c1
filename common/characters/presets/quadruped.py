"""The paper's quadruped: head, trunk and four legs (hips 3 DOF, knees 1 DOF, ankles 2 DOF).

A dog-sized body built in code (MuJoCo Z up, facing +X): trunk 0.70 x 0.24 x 0.16 m box (root,
20 kg), head on a ball `neck`, legs `fl`, `fr`, `hl`, `hr` (front/hind, left/right), each a
thigh (ball `<leg>_hip`), shank (hinge `<leg>_knee` about Y) and box foot (hinges
`<leg>_ankle_pitch` about Y and `<leg>_ankle_roll` about X). Standing height ~0.65 m, ~36 kg.
Dimensions and gains are this project's choice (the paper gives none).
"""

from __future__ import annotations

from common.characters import builder
from common.characters.builder import BaseCharacter, GeomDef, JointDef
from common.characters.shape_space import BodyPart, ShapeParam, ShapeSpace, random_space, uniform_space

LEGS = {"fl": (0.30, 0.11), "fr": (0.30, -0.11), "hl": (-0.30, 0.11), "hr": (-0.30, -0.11)}
THIGH_M, SHANK_M = 0.24, 0.24
SHANK_R, SHANK_HALF = 0.02, 0.09
"""The shank is a capsule of radius 2 cm from 2 cm below the knee to 4 cm above the ankle
(its round end 2 cm clear of the ankle); the foot box reaches 2 cm above the ankle to meet it.
The shape operator scales a capsule's radius with the segment's width and its length with its
height, so a shank 3 cm thick reaching 1 cm past the ankle hangs below the foot's sole on short,
wide shapes (13.7% of the 300 evaluation shapes in the retargeted trot, 22.7% within 5 mm) and
stands on the floor, a fall by Won & Lee's rule from the first step. With this one no shape's
reference puts a shank into the floor (4 of 300 within 5 mm, in the trot's steepest frames;
`morphmimic evaluate` tables falls by this clearance; docs/experiments/2026-12-04-quadruped-shank.md)."""


def build(timestep_s: float) -> BaseCharacter:
    """Quadruped with PD actuators (see builder.py)."""
    spec = builder.new_world("quadruped", timestep_s, swimmer=False)
    trunk = builder.add_body(spec.worldbody, "trunk", (0.0, 0.0, 0.6), [GeomDef("box", (0.35, 0.12, 0.08), 20.0)], free=True)
    joints = [JointDef("neck", "ball", 200.0, 20.0, 60.0, ((-0.5, 0.5), (-0.8, 0.8), (-0.8, 0.8)))]
    builder.add_body(trunk, "head", (0.35, 0.0, 0.05), [GeomDef("box", (0.1, 0.07, 0.06), 3.0, (0.1, 0.0, 0.04))], joints)
    parts = [BodyPart("trunk", ("trunk",), 0), BodyPart("head", ("head",), 0)]
    feet = []
    for leg, (x, y) in LEGS.items():
        end = "front" if leg[0] == "f" else "hind"
        side = "left" if leg[1] == "l" else "right"
        groups = ("leg", f"leg_{end}", f"leg_{side}")
        hip = JointDef(f"{leg}_hip", "ball", 300.0, 30.0, 120.0, ((-0.6, 0.6), (-1.2, 1.2), (-0.6, 0.6)))
        knee = JointDef(f"{leg}_knee", "hinge", 300.0, 30.0, 120.0, ((-2.4, 2.4),), axis=(0.0, 1.0, 0.0))
        ankle = [
            JointDef(f"{leg}_ankle_pitch", "hinge", 100.0, 10.0, 40.0, ((-1.0, 1.0),), axis=(0.0, 1.0, 0.0)),
            JointDef(f"{leg}_ankle_roll", "hinge", 100.0, 10.0, 40.0, ((-0.5, 0.5),), axis=(1.0, 0.0, 0.0)),
        ]
        thigh = builder.add_body(trunk, f"{leg}_thigh", (x, y, -0.05),
                                 [GeomDef("capsule", (0.04, THIGH_M / 2 - 0.02), 2.0, (0.0, 0.0, -THIGH_M / 2))], [hip])
        shank = builder.add_body(thigh, f"{leg}_shank", (0.0, 0.0, -THIGH_M),
                                 [GeomDef("capsule", (SHANK_R, SHANK_HALF), 1.0, (0.0, 0.0, -0.02 - SHANK_HALF))], [knee])
        builder.add_body(shank, f"{leg}_foot", (0.0, 0.0, -SHANK_M),
                         [GeomDef("box", (0.06, 0.04, 0.03), 0.3, (0.02, 0.0, -0.01))], ankle)
        joints += [hip, knee, *ankle]
        parts += [BodyPart(f"{leg}_thigh", groups, 2), BodyPart(f"{leg}_shank", groups, 2),
                  BodyPart(f"{leg}_foot", ("foot",), 0)]
        feet.append(f"{leg}_foot")
    builder.add_pd_actuators(spec, joints)
    builder.add_tracking_camera(trunk, 2.5, 0.3)
    parts_t = tuple(parts)
    spaces = {s.name: s for s in (random_space(parts_t), uniform_space(), *quadruped_spaces())}
    return BaseCharacter(
        preset="quadruped", spec=spec, parts=parts_t, spaces=spaces, foot_geoms=tuple(feet),
        legs=tuple((f"{leg}_thigh", f"{leg}_foot") for leg in LEGS), end_effector_bodies=(*feet, "head"),
        root_body="trunk",
    )


def quadruped_spaces() -> list[ShapeSpace]:
    """Front vs hind legs, left vs right legs, height vs thickness."""
    return [
        ShapeSpace("front_hind_leg", (
            ShapeParam("front_leg", 0.5, 1.5, ("leg_front",), "long", "length of the front thighs and shanks"),
            ShapeParam("hind_leg", 0.5, 1.5, ("leg_hind",), "long", "length of the hind thighs and shanks"),
        ), "front vs hind leg length, x0.5..x1.5 each"),
        ShapeSpace("left_right_leg", (
            ShapeParam("left_leg", 0.9, 1.1, ("leg_left",), "long", "length of the left legs"),
            ShapeParam("right_leg", 0.9, 1.1, ("leg_right",), "long", "length of the right legs"),
        ), "left vs right leg length, each +-10%"),
        ShapeSpace("height_thickness", (
            ShapeParam("height", 0.75, 1.5, ("*",), "long", "length of every segment along its bone"),
            ShapeParam("thickness", 0.5, 1.5, ("*",), "thick", "cross-section of every segment"),
        ), "height x0.75..x1.5 vs thickness x0.5..x1.5"),
    ]
