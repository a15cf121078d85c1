"""Base characters: structure others rely on (motion library joint names, feet, DOFs)."""

from __future__ import annotations

import mujoco
import numpy as np

from common.characters import load_character
from common.characters.presets.humanoid import DEEPMIMIC_JOINT_ORDER


def test_humanoid_has_deepmimic_joints():
    ch = load_character("humanoid")
    assert sorted(ch.joint_names) == sorted(DEEPMIMIC_JOINT_ORDER)
    assert ch.model.nbody - 1 == 15
    assert abs(ch.mass_kg - 45.0) < 1e-6
    assert abs(ch.height_m - 1.62) < 0.02
    kinds = {n: ch.model.jnt_type[ch.model.joint(n).id] for n in ch.joint_names}
    assert kinds["right_knee"] == mujoco.mjtJoint.mjJNT_HINGE and kinds["chest"] == mujoco.mjtJoint.mjJNT_BALL
    assert ch.qpos_slices["chest"].stop - ch.qpos_slices["chest"].start == 4
    assert ch.dof == 28 == ch.model.nu


def test_biped_is_mass_without_toes():
    ch = load_character("biped")
    names = {ch.model.body(i).name for i in range(1, ch.model.nbody)}
    assert len(names) == 19
    assert {"Pelvis", "FemurR", "TibiaR", "TalusR", "Spine", "Torso", "Neck", "Head", "ShoulderR", "ArmR", "ForeArmR",
            "HandR", "HandL"} <= names
    assert not any("Foot" in n for n in names)
    hinges = [n for n in ch.joint_names if ch.model.jnt_type[ch.model.joint(n).id] == mujoco.mjtJoint.mjJNT_HINGE]
    assert sorted(hinges) == ["ForeArmL", "ForeArmR", "TibiaL", "TibiaR"]
    assert abs(ch.height_m - 1.70) < 0.03
    assert ch.foot_bodies == ("TalusR", "TalusL")


def test_quadruped_joint_structure():
    ch = load_character("quadruped")
    m = ch.model
    for leg in ("fl", "fr", "hl", "hr"):
        assert m.jnt_type[m.joint(f"{leg}_hip").id] == mujoco.mjtJoint.mjJNT_BALL
        assert m.jnt_type[m.joint(f"{leg}_knee").id] == mujoco.mjtJoint.mjJNT_HINGE
        assert m.body(f"{leg}_foot").jntnum[0] == 2
    assert len(ch.leg_lengths_m) == 4


def test_swimmers_float_in_water():
    for preset, nbody in (("fish", 6), ("manta", 8)):
        ch = load_character(preset)
        assert ch.is_swimmer and ch.model.nbody - 1 == nbody
        assert ch.model.opt.density == 1000.0 and not np.any(ch.model.opt.gravity)
        body_geoms = [g for g in range(ch.model.ngeom) if ch.model.geom_bodyid[g] > 0]
        assert all(ch.model.geom_fluid[g, 0] == 1.0 for g in body_geoms)
