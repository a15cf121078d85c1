"""A clip on a character: qpos mapping, velocities, end effectors, COM (MuJoCo kinematics)."""

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from common.motion import kinematics
from common.motion.import_bvh import load_bvh
from common.motion.reference import CharacterMotion

from .conftest import MASS, base_character


def test_body_orientations_compose_the_clip_rotations(walk_clip):
    """World orientation of the shank = root * hip * knee (world-aligned rest frames)."""
    ch = base_character("humanoid")
    motion = CharacterMotion.from_clip(walk_clip, ch.model, tuple(ch.end_effector_bodies))
    data = mujoco.MjData(ch.model)
    data.qpos[:] = motion.qpos(0.5)
    mujoco.mj_kinematics(ch.model, data)
    pose = kinematics.sample(walk_clip, 0.5)
    sl = walk_clip.joint_slices()
    hip = pose.joint_qpos[sl[walk_clip.joint_names.index("right_hip")]]
    knee = pose.joint_qpos[sl[walk_clip.joint_names.index("right_knee")]][0]
    expected = (Rotation.from_quat(pose.root_quat, scalar_first=True) * Rotation.from_quat(hip, scalar_first=True)
                * Rotation.from_rotvec(knee * np.array([0, -1.0, 0])))
    got = Rotation.from_quat(data.xquat[ch.model.body("right_knee").id], scalar_first=True)
    assert (got * expected.inv()).magnitude() < 1e-9


def test_qvel_integrates_to_the_next_pose(walk_clip):
    ch = base_character("humanoid")
    motion = CharacterMotion.from_clip(walk_clip, ch.model)
    t, h = 0.51, 1e-3
    q = motion.qpos(t).copy()
    mujoco.mj_integratePos(ch.model, q, motion.qvel(t, h_s=h), 2 * h)
    q_next = motion.qpos(t + 2 * h)
    diff = np.zeros(ch.model.nv)
    mujoco.mj_differentiatePos(ch.model, diff, 1.0, q_next, q)
    assert np.abs(diff).max() < 1e-3
    assert np.abs(motion.qvel(t)).max() > 0.5  # the walk moves


def test_state_has_end_effectors_and_com(walk_clip):
    ch = base_character("humanoid")
    motion = CharacterMotion.from_clip(walk_clip, ch.model, tuple(ch.end_effector_bodies))
    s = motion.state(0.3)
    assert s.end_effectors.shape == (len(ch.end_effector_bodies), 3)
    feet = s.end_effectors[:2, 2]
    assert feet.min() < 0.12 and s.com[2] > 0.6  # one ankle near the floor
    # forward walking speed about 1 m/s, from the COM velocity
    assert 0.6 < s.com_vel[0] < 1.6


def test_loop_continues_forward_on_the_character(walk_clip):
    ch = base_character("humanoid")
    motion = CharacterMotion.from_clip(walk_clip, ch.model)
    d = motion.duration_s
    assert motion.qpos(0.2 + 3 * d)[0] - motion.qpos(0.2)[0] == pytest.approx(3 * (walk_clip.root_pos[-1, 0] - walk_clip.root_pos[0, 0]))


def test_mass_clip_drives_every_biped_joint():
    ch = base_character("biped")
    clip = load_bvh(MASS / "walk.bvh")
    from common.motion.qpos_map import QposMap

    qmap = QposMap(clip, ch.model)
    assert qmap.undriven == ()
    motion = CharacterMotion.from_clip(clip, ch.model)
    knee = ch.model.jnt_qposadr[ch.model.joint("TibiaR").id]
    assert np.ptp(motion.qpos_frames[:, knee]) > 0.5  # knees bend during a walk
