"""The paper's lower-body biped: torso, hip (pelvis) and two legs, cut from the MASS skeleton.

Bodies `Pelvis` (root, the hip), `Spine` (the torso: a ball joint at MASS's lower spine joint, carrying MASS's Spine
and Torso boxes, 15 kg), `FemurR/L`, `TibiaR/L`, `TalusR/L`; axes and gains as in biped.py.
"""

from __future__ import annotations

from dataclasses import replace

from common.characters import builder
from common.characters.builder import BaseCharacter
from common.characters.presets.biped import build_mass_tree, parse_mass
from common.characters.presets.humanoid import biped_spaces
from common.characters.shape_space import random_space, uniform_space

LEGS = ["FemurR", "TibiaR", "TalusR", "FemurL", "TibiaL", "TalusL"]


def build(timestep_s: float) -> BaseCharacter:
    """Lower-body biped with PD actuators (see builder.py)."""
    nodes = parse_mass()
    # The torso is MASS's Spine node (its joint) carrying the Torso box as a second geom.
    nodes["Spine"] = replace(nodes["Spine"], parent="Pelvis")
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
