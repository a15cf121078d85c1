"""The paper's manta ray: a trunk, two wings of 3 bodies each, and a tail, swimming in water.

Built in code (facing +X, wings along +-Y): `trunk` (root, flat ellipsoid), wings
`wing_left1..3` / `wing_right1..3` outward, each joined by a flap hinge `<wing>_flap` (about X)
and a twist hinge `<wing>_twist` (about Y), and a `tail` (yaw and pitch hinges). Flat
ellipsoids with `fluid_ellipsoid` at water density, no gravity (see fish.py). Span ~1.4 m.
Flapping the wings with a phase lag along the span (a travelling wave) swims it forward.
"""

from __future__ import annotations

from common.characters import builder
from common.characters.builder import WATER_DENSITY_KG_M3, BaseCharacter, GeomDef, JointDef, volume
from common.characters.presets.swimmer_spaces import swimmer_spaces
from common.characters.shape_space import BodyPart, random_space, uniform_space

TRUNK = (0.25, 0.15, 0.05)  # half-sizes [m]
WING = [(0.22, 0.24, 0.02), (0.17, 0.2, 0.014), (0.11, 0.16, 0.01)]  # (half chord X, span Y, half thickness Z)


def _geom(size, pos) -> GeomDef:
    return GeomDef("ellipsoid", size, WATER_DENSITY_KG_M3 * volume("ellipsoid", size), pos)


def build(timestep_s: float) -> BaseCharacter:
    """The manta ray with PD actuators (see builder.py)."""
    spec = builder.new_world("manta", timestep_s, swimmer=True)
    trunk = builder.add_body(spec.worldbody, "trunk", (0.0, 0.0, 1.0), [_geom(TRUNK, (0.0, 0.0, 0.0))], swimmer=True, free=True)
    joints = []
    parts = [BodyPart("trunk", ("body", "trunk"), 0)]
    for side, sign in (("left", 1.0), ("right", -1.0)):
        parent, offset = trunk, TRUNK[1] * 0.8
        for k, (chord, span, thick) in enumerate(WING, start=1):
            name = f"wing_{side}{k}"
            js = [JointDef(f"{name}_flap", "hinge", 60.0, 6.0, 40.0, ((-0.8, 0.8),), axis=(sign, 0.0, 0.0)),
                  JointDef(f"{name}_twist", "hinge", 30.0, 3.0, 20.0, ((-0.4, 0.4),), axis=(0.0, 1.0, 0.0))]
            parent = builder.add_body(parent, name, (0.0, sign * offset, 0.0),
                                      [_geom((chord, span / 2.0, thick), (-0.03 * k, sign * span / 2.0, 0.0))], js, swimmer=True)
            offset = span
            joints += js
            parts.append(BodyPart(name, ("body", "wing", f"wing_{side}"), 1))
    tail_js = [JointDef("tail_yaw", "hinge", 10.0, 1.0, 5.0, ((-0.6, 0.6),), axis=(0.0, 0.0, 1.0)),
               JointDef("tail_pitch", "hinge", 10.0, 1.0, 5.0, ((-0.4, 0.4),), axis=(0.0, 1.0, 0.0))]
    builder.add_body(trunk, "tail", (-TRUNK[0], 0.0, 0.0), [_geom((0.2, 0.012, 0.012), (-0.2, 0.0, 0.0))], tail_js, swimmer=True)
    joints += tail_js
    parts.append(BodyPart("tail", ("body", "tail"), 0))
    builder.add_pd_actuators(spec, joints)
    builder.add_tracking_camera(trunk, 2.5, 1.0)
    parts_t = tuple(parts)
    spaces = {s.name: s for s in (random_space(parts_t), uniform_space(), *swimmer_spaces(("wing",)))}
    return BaseCharacter(preset="manta", spec=spec, parts=parts_t, spaces=spaces,
                         end_effector_bodies=("wing_left3", "wing_right3", "tail"), is_swimmer=True, root_body="trunk")
