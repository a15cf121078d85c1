import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from common.motion import kinematics, quat

from .test_clip import tiny_clip


def spinning_clip(rate_rad_s=2.0, fps=10.0, n=11, loop=False):
    """Root turning about z and walking along x at 1 m/s; hip turning about x; knee linear."""
    t = np.arange(n) / fps
    root_q = quat.wxyz(Rotation.from_rotvec(np.outer(rate_rad_s * t, [0, 0, 1])))
    hip_q = quat.wxyz(Rotation.from_rotvec(np.outer(0.5 * rate_rad_s * t, [1, 0, 0])))
    root_pos = np.stack([t, np.zeros(n), np.full(n, 0.9)], axis=1)
    jq = np.concatenate([quat.continuous(hip_q), 0.1 * t[:, None]], axis=1)
    return tiny_clip(fps=fps, root_pos=root_pos, root_quat=quat.continuous(root_q), joint_qpos=jq, loop=loop)


def test_sample_hits_frames_and_slerps_between():
    clip = spinning_clip()
    p = kinematics.sample(clip, 0.3)
    np.testing.assert_allclose(p.root_quat, clip.root_quat[3], atol=1e-12)
    mid = kinematics.sample(clip, 0.35)
    # slerp: the angle halfway between frames is the mean angle (constant-rate rotation).
    assert Rotation.from_quat(mid.root_quat, scalar_first=True).magnitude() == pytest.approx(2.0 * 0.35)
    assert mid.joint_qpos[4] == pytest.approx(0.035)


def test_velocity_uses_quaternion_differences():
    clip = spinning_clip(rate_rad_s=3.0)
    v = kinematics.velocity(clip, 0.42)
    np.testing.assert_allclose(v.root_ang, [0, 0, 3.0], atol=1e-9)
    np.testing.assert_allclose(v.root_lin, [1.0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(v.joint, [1.5, 0, 0, 0.1], atol=1e-9)


def test_velocity_is_the_short_way_round():
    # A component-wise difference of q and -q would be huge; the rotation is the same.
    clip = spinning_clip()
    flipped = clip.joint_qpos.copy()
    flipped[5:, :4] *= -1
    v = kinematics.velocity(clip.with_(joint_qpos=flipped), 0.47)
    np.testing.assert_allclose(v.joint[:3], [1.0, 0, 0], atol=1e-9)


def test_loop_accumulates_root_displacement(walk_clip):
    d = walk_clip.duration_s
    for t in (0.3, 0.71):
        a, b = kinematics.sample(walk_clip, t), kinematics.sample(walk_clip, t + 2 * d)
        step = walk_clip.root_pos[-1, :2] - walk_clip.root_pos[0, :2]
        np.testing.assert_allclose(b.root_pos[:2], a.root_pos[:2] + 2 * step, atol=1e-12)
        assert b.root_pos[2] == pytest.approx(a.root_pos[2])
        np.testing.assert_allclose(b.joint_qpos, a.joint_qpos, atol=1e-12)
    assert step[0] > 1.0  # the walk moves forward, so the test means something


def test_non_looping_clip_holds_last_frame():
    clip = spinning_clip(loop=False)
    p = kinematics.sample(clip, 5.0)
    np.testing.assert_allclose(p.root_pos, clip.root_pos[-1])


def test_array_times_match_scalar_times(walk_clip):
    ts = np.array([0.0, 0.2, 1.9])
    batch = kinematics.sample(walk_clip, ts)
    for i, t in enumerate(ts):
        np.testing.assert_allclose(batch.joint_qpos[i], kinematics.sample(walk_clip, t).joint_qpos)
