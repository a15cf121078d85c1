"""The paper's fish: 6 bodies in a row, swimming in water through MuJoCo's fluid model.

Built in code (facing +X): `head` (root) and `seg1`..`seg5` towards the tail, each joined by a
yaw hinge `<seg>_yaw` (about Z) and a pitch hinge `<seg>_pitch` (about Y); the last segment
carries a tall thin caudal fin. Every geom is an ellipsoid with `fluid_ellipsoid` on (lift and
drag from MuJoCo's ellipsoid model) at water density, so the fish is neutrally buoyant; the
world has no gravity (builder.new_world). ~0.95 m long, ~6 kg. A travelling wave of yaw
targets makes it swim forward.
"""

from __future__ import annotations

from common.characters import builder
from common.characters.builder import WATER_DENSITY_KG_M3, BaseCharacter, GeomDef, JointDef, volume
from common.characters.presets.swimmer_spaces import swimmer_spaces
from common.characters.shape_space import BodyPart, random_space, uniform_space

# (name, length along X [m], half-width Y [m], half-height Z [m])
SEGMENTS = [("head", 0.24, 0.06, 0.09), ("seg1", 0.16, 0.055, 0.09), ("seg2", 0.15, 0.05, 0.08),
            ("seg3", 0.13, 0.04, 0.065), ("seg4", 0.12, 0.03, 0.045), ("seg5", 0.12, 0.008, 0.14)]


def _ellipsoid(length: float, half_y: float, half_z: float) -> GeomDef:
    size = (length / 2.0, half_y, half_z)
    return GeomDef("ellipsoid", size, WATER_DENSITY_KG_M3 * volume("ellipsoid", size), (-length / 2.0, 0.0, 0.0))


def build(timestep_s: float) -> BaseCharacter:
    """The fish with PD actuators (see builder.py)."""
    spec = builder.new_world("fish", timestep_s, swimmer=True)
    name, length, hy, hz = SEGMENTS[0]
    head = builder.add_body(spec.worldbody, name, (0.0, 0.0, 1.0), [_ellipsoid(length, hy, hz)], swimmer=True, free=True)
    parent, parent_len = head, length
    joints = []
    parts = [BodyPart(name, ("body", "head"), 0)]
    for name, length, hy, hz in SEGMENTS[1:]:
        js = [JointDef(f"{name}_yaw", "hinge", 50.0, 5.0, 30.0, ((-0.8, 0.8),), axis=(0.0, 0.0, 1.0)),
              JointDef(f"{name}_pitch", "hinge", 50.0, 5.0, 30.0, ((-0.4, 0.4),), axis=(0.0, 1.0, 0.0))]
        parent = builder.add_body(parent, name, (-parent_len, 0.0, 0.0), [_ellipsoid(length, hy, hz)], js, swimmer=True)
        parent_len = length
        joints += js
        parts.append(BodyPart(name, ("body", "tail" if name == "seg5" else "trunk"), 0))
    builder.add_pd_actuators(spec, joints)
    builder.add_tracking_camera(head, 2.0, 0.6)
    parts_t = tuple(parts)
    spaces = {s.name: s for s in (random_space(parts_t), uniform_space(), *swimmer_spaces(None))}
    return BaseCharacter(preset="fish", spec=spec, parts=parts_t, spaces=spaces, end_effector_bodies=("head", "seg5"),
                         is_swimmer=True, root_body="head")
