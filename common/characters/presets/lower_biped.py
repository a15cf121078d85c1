"""The paper's lower-body biped: torso, hip (pelvis) and two legs, cut from the MASS skeleton.

Bodies `Pelvis` (root, the hip), `Spine` (the torso: a ball joint at MASS's lower spine joint, carrying MASS's Spine
and Torso boxes, 15 kg), `FemurR/L`, `TibiaR/L`, `TalusR/L`; axes and gains as in biped.py.

The shank box is slimmer than MASS's (`shank_box`): MASS keeps the calf's full 11.4 cm depth down to
1.6 cm above the ankle joint, and as the shank tilts in the walk the box's lower edge sweeps down
by half that depth; the random space scales the depth by up to 1.5 and the height by down to 0.5,
so on short, deep shapes the retargeted walk itself put a shank into the floor (a fall by the
paper's rule).
"""

from __future__ import annotations

from dataclasses import replace

from common.characters import builder
from common.characters.builder import BaseCharacter
from common.characters.presets.biped import MassNode, build_mass_tree, parse_mass
from common.characters.presets.humanoid import biped_spaces
from common.characters.shape_space import random_space, uniform_space

LEGS = ["FemurR", "TibiaR", "TalusR", "FemurL", "TibiaL", "TalusL"]
SHANK_RAISE_M = 0.04
"""The shank box ends this much higher above the ankle than MASS's (its top, at the knee, stays)."""
SHANK_DEPTH_FACTOR = 0.6
"""The shank box's front-to-back depth against MASS's 11.4 cm: 6.8 cm, about a shank's at the ankle."""


def shank_box(node: MassNode) -> MassNode:
    """MASS's tibia node with its box shortened from the ankle end by `SHANK_RAISE_M` and its depth
    scaled by `SHANK_DEPTH_FACTOR`; the mass stays (the density follows), so the segment's inertia
    changes only by the box's shape. Chosen by a probe of the retargeted walk (contact_smooth) over
    the 300 evaluation shapes (seed 2019): the lowest point of any shank reached -14.3 mm with MASS's
    box (7 shapes under 0, 32 under 20 mm); shortened 4 cm, -6.5 mm (3, 21); depth x0.75, 0.1 mm (0,
    15); both changes, 16.6 mm (0, 3). Falls on those shapes: docs/shape-controllers.md, "The lower
    biped's shank"."""
    half = node.half_size.copy()
    half[1] -= SHANK_RAISE_M / 2  # the box's local y is the shank's long axis, +y toward the ankle
    half[2] *= SHANK_DEPTH_FACTOR  # local z is front to back
    return replace(node, half_size=half, box_pos=node.box_pos - (SHANK_RAISE_M / 2) * node.box_rot[:, 1])


def build(timestep_s: float) -> BaseCharacter:
    """Lower-body biped with PD actuators (see builder.py)."""
    nodes = parse_mass()
    # The torso is MASS's Spine node (its joint) carrying the Torso box as a second geom.
    nodes["Spine"] = replace(nodes["Spine"], parent="Pelvis")
    for side in "RL":
        nodes[f"Tibia{side}"] = shank_box(nodes[f"Tibia{side}"])
    spec = builder.new_world("lower_biped", timestep_s, swimmer=False)
    bodies, joints, parts = build_mass_tree(spec, nodes, ["Pelvis", *LEGS, "Spine"], extra_geoms={"Spine": ("Torso",)})
    builder.add_pd_actuators(spec, joints)
    builder.add_tracking_camera(bodies["Pelvis"], 2.5, 0.3)
    parts_t = tuple(parts)
    spaces = {s.name: s for s in (random_space(parts_t), uniform_space(), *biped_spaces(None))}
    return BaseCharacter(
        preset="lower_biped", spec=spec, parts=parts_t, spaces=spaces, foot_geoms=("TalusR", "TalusL"),
        legs=(("FemurR", "TalusR"), ("FemurL", "TalusL")), end_effector_bodies=("TalusR", "TalusL", "Spine"),
        root_body="Pelvis",
    )
