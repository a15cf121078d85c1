"""A clip's mirror image (`common.motion.mirror`): every body of the mirrored motion is where the
reflection puts its partner in the original, on the humanoid (hinges about y) and on the biped
(elbow hinges about z, whose angle changes sign); mirroring twice gives the clip back; skeletons
and bodies that are not left-right symmetric are refused by name."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from common.characters import load_character
from common.motion.errors import ClipError
from common.motion.library import MotionLibrary
from common.motion.mirror import check_symmetric, mirror_clip, mirrored_id, partner_name, partners, source_id
from common.motion.reference import CharacterMotion

FLIP = np.array([1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def lib() -> MotionLibrary:
    return MotionLibrary()


def test_partner_names() -> None:
    pairs = {"left_hip": "right_hip", "right_elbow": "left_elbow", "FemurL": "FemurR", "HandR": "HandL",
             "LeftUpLeg": "RightUpLeg", "hip_l": "hip_r", "chest": "chest", "Spine": "Spine", "lowerback": "lowerback"}
    assert {n: partner_name(n) for n in pairs} == pairs
    assert mirrored_id("humanoid/mass_kick") == "humanoid/mass_kick~mirror"
    assert source_id(mirrored_id("humanoid3d_walk")) == "humanoid3d_walk"
    assert mirrored_id(mirrored_id("humanoid3d_walk")) == "humanoid3d_walk"


# NOTE: the MASS biped's model is symmetric to within 0.4 mm (its mesh-fitted offsets), the humanoid exactly.
@pytest.mark.parametrize("clip_id, preset, atol", [("humanoid3d_kick", "humanoid", 1e-9),
                                                   ("humanoid3d_cartwheel", "humanoid", 1e-9), ("mass/walk", "biped", 1e-3)])
def test_every_body_of_the_mirror_image_is_where_its_partner_was_reflected(lib: MotionLibrary, clip_id: str,
                                                                           preset: str, atol: float) -> None:
    model = load_character(preset).model
    clip = lib.clip(clip_id)
    here = CharacterMotion.from_clip(clip, model)
    there = CharacterMotion.from_clip(mirror_clip(clip), model)
    names = [model.body(i).name for i in range(model.nbody)]
    partner = [names.index(partner_name(n)) for n in names]
    for t in np.linspace(0.0, clip.duration_s, 7):
        pos, _ = here.positions(here.qpos(t))
        mirrored, _ = there.positions(there.qpos(t))
        np.testing.assert_allclose(mirrored[partner], pos * FLIP, atol=atol)


def test_mirroring_twice_gives_the_clip_back(lib: MotionLibrary) -> None:
    clip = lib.clip("humanoid3d_spinkick")
    twice = mirror_clip(mirror_clip(clip))
    assert twice.name == clip.name
    for key in ("root_pos", "root_quat", "joint_qpos"):
        np.testing.assert_allclose(getattr(twice, key), getattr(clip, key), atol=1e-12)


def test_library_serves_mirror_images_by_id_with_the_source_label(lib: MotionLibrary) -> None:
    m = lib.clip("humanoid/mass_kick~mirror")
    assert (m.name, m.label, m.extra["mirror_of"]) == ("humanoid/mass_kick~mirror", lib.clip("humanoid/mass_kick").label,
                                                        "humanoid/mass_kick")
    assert lib.play("humanoid3d_kick~mirror", load_character("humanoid")).duration_s == pytest.approx(
        lib.clip("humanoid3d_kick").duration_s)


def test_a_one_sided_skeleton_is_refused_by_name(lib: MotionLibrary) -> None:
    with pytest.raises(ClipError, match="joint 'left_arm' has no mirror partner 'right_arm'"):
        partners(("chest", "left_arm"))
    clip = lib.clip("humanoid3d_walk")
    bad = clip.with_(hinge_axes=clip.hinge_axes * 0 + np.array([[0.0, 0.0, 0.0]] * 3 + [[1.0, 0.0, 0.0]] + [[0.0] * 3] * 8))
    with pytest.raises(ClipError, match="hinge 'right_knee' turns about .* not mirror images"):
        mirror_clip(bad)


def test_an_asymmetric_body_is_refused() -> None:
    ch = load_character("lower_biped", shape={"left_leg": 1.1}, parameterization="left_right_leg")
    data = mujoco.MjData(ch.model)
    mujoco.mj_kinematics(ch.model, data)
    with pytest.raises(ClipError, match="not left-right symmetric .* mm from mirror images"):
        check_symmetric(ch.model, data)
    base = load_character("lower_biped").model
    data = mujoco.MjData(base)
    mujoco.mj_kinematics(base, data)
    check_symmetric(base, data)
