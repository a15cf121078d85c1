"""Reference cleaning (common/motion/clean.py): the zero-phase filter on hinges and rotations, the
floor rule, the MimicKit/PHC widened PD ranges, and the statistics `motion check` prints."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from common.motion import clean
from common.motion.reference import CharacterMotion, model_clip

from .conftest import base_character


def humanoid_motion(qpos: np.ndarray, fps: float) -> CharacterMotion:
    model = base_character("humanoid").model
    template = model_clip(_blank_clip(), model, qpos, fps)
    return CharacterMotion(template, model, qpos)


def _blank_clip():
    from common.motion.clip import Clip

    return Clip(name="synthetic", fps=60.0, root_pos=np.zeros((1, 3)), root_quat=np.array([[1.0, 0, 0, 0]]),
                joint_names=(), joint_types=(), joint_qpos=np.zeros((1, 0)), hinge_axes=np.zeros((0, 3)))


def rest_frames(n: int) -> np.ndarray:
    model = base_character("humanoid").model
    q = np.tile(model.qpos0, (n, 1))
    q[:, 2] = 1.0
    return q


def test_filter_rows_sum_to_one_and_pass_slow_tracks():
    m = clean.filter_matrix(200, 120.0, 7.0)
    np.testing.assert_allclose(m.sum(axis=1), 1.0, atol=1e-9)
    t = np.arange(200) / 120.0
    slow, fast = np.sin(2 * math.pi * 1.0 * t), np.sin(2 * math.pi * 25.0 * t)
    assert np.abs(m @ slow - slow)[20:-20].max() < 0.01
    assert np.abs(m @ fast)[20:-20].max() < 0.05


def test_filter_smooths_a_hinge_and_keeps_a_fast_spin_of_the_root():
    model = base_character("humanoid").model
    n, fps = 481, 120.0
    t = np.arange(n) / fps
    q = rest_frames(n)
    knee = int(model.jnt_qposadr[model.joint("right_knee").id])
    q[:, knee] = -1.0 + 0.3 * np.sin(2 * math.pi * 0.5 * t) + 0.2 * np.sign(np.sin(2 * math.pi * 30.0 * t + 0.1))
    yaw = 2 * math.pi * 2.0 * t  # two turns a second: far past pi within the filter's span
    q[:, 3:7] = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=1)
    chest = int(model.jnt_qposadr[model.joint("chest").id])
    q[:, chest:chest + 4] = q[:, 3:7]
    motion = humanoid_motion(q, fps)
    out, fps_out = clean.filter_qpos(model, motion, 7.0)
    assert fps_out >= clean.FILTER_GRID_HZ and len(out) == int(round(4.0 * fps_out)) + 1
    tt = np.linspace(0, 4.0, len(out))
    inner = slice(len(out) // 8, -len(out) // 8)
    smooth = -1.0 + 0.3 * np.sin(2 * math.pi * 0.5 * tt)
    assert np.abs(out[inner, knee] - smooth[inner]).max() < 0.03  # the 30 Hz square wave is gone
    for cols in (slice(3, 7), slice(chest, chest + 4)):  # the steady spin is untouched (sign aside)
        want = np.stack([np.cos(2 * math.pi * tt), 0 * tt, 0 * tt, np.sin(2 * math.pi * tt)], axis=1)
        assert np.abs(np.abs(np.sum(out[:, cols] * want, axis=1)) - 1.0).max() < 1e-6
        np.testing.assert_allclose(np.linalg.norm(out[:, cols], axis=1), 1.0)
    np.testing.assert_allclose(out[:, 0:3], np.tile(q[0, 0:3], (len(out), 1)), atol=1e-9)


def test_clean_motion_off_is_the_same_motion_and_floor_lifts_only_sunk_frames(walk_clip):
    model = base_character("humanoid").model
    motion = CharacterMotion.from_clip(walk_clip.with_(loop=False), model)
    assert clean.clean_motion(motion) is motion
    q = motion.qpos_frames.copy()
    q[: len(q) // 2, 2] -= 0.05  # the first half sunk 5 cm
    q[len(q) // 2:, 2] += 0.20  # the second half floating
    sunk = CharacterMotion(motion.clip, model, q)
    lifted = clean.clean_motion(sunk, floor=True)
    low = clean.lowest_geom_heights(model, lifted.qpos_frames)
    assert low.min() > -1e-9 and np.abs(low[: len(q) // 2]).max() < 1e-9
    np.testing.assert_array_equal(lifted.qpos_frames[len(q) // 2:], q[len(q) // 2:])
    assert lifted.duration_s == pytest.approx(motion.duration_s)


def test_cleaning_the_backflip_lowers_its_velocity_jumps_and_its_sink():
    from common.motion.library import MotionLibrary

    model = base_character("humanoid").model
    raw = CharacterMotion.from_clip(MotionLibrary().clip("humanoid3d_backflip").with_(loop=False), model)
    cleaned = clean.clean_motion(raw, 7.0, True)
    assert cleaned.duration_s == pytest.approx(raw.duration_s) and cleaned.frames.fps >= clean.FILTER_GRID_HZ
    tol = math.log(10) / 0.1
    a, b = clean.reference_stats(raw, 1 / 60, tol), clean.reference_stats(cleaned, 1 / 60, tol)
    assert b.velocity_jump_max < 0.5 * a.velocity_jump_max and b.velocity_jump_share < a.velocity_jump_share
    assert a.sink_worst_m < -0.02 and b.sink_worst_m > -0.002 and b.below_share == 0.0
    assert "vel jump max" in b.line()


def test_widened_ranges_follow_mimickit_and_phc():
    model = base_character("humanoid").model
    wide = clean.widen_ranges(model)
    own = model.actuator_ctrlrange
    for a in range(model.nu):
        name = model.actuator(a).name
        j = int(model.actuator_trnid[a, 0])
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL:
            acts = [b for b in range(model.nu) if model.actuator_trnid[b, 0] == j]
            scale = min(1.2 * np.abs(own[acts]).max(), math.pi)
            np.testing.assert_allclose(wide[a], [-scale, scale], err_msg=name)
        else:
            mid, half = own[a].mean(), 0.5 * (own[a, 1] - own[a, 0])
            np.testing.assert_allclose(wide[a], [mid - 1.4 * half, mid + 1.4 * half], err_msg=name)
    elbow = model.actuator("right_elbow").id
    np.testing.assert_allclose(wide[elbow], [-0.2 * 3.14, 1.2 * 3.14])
    np.testing.assert_allclose(wide[model.actuator("chest_x").id], [-1.44, 1.44])
    assert np.all(wide[:, 0] <= own[:, 0]) and np.all(wide[:, 1] >= own[:, 1])
