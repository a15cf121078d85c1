import numpy as np
import pytest

from common.motion.clip import Clip, load_clip
from common.motion.errors import ClipError


def tiny_clip(**changes) -> Clip:
    t = 3
    fields = dict(
        name="tiny", fps=10.0, root_pos=np.zeros((t, 3)), root_quat=np.tile([1.0, 0, 0, 0], (t, 1)),
        joint_names=("hip", "knee"), joint_types=("ball", "hinge"),
        joint_qpos=np.tile([1.0, 0, 0, 0, 0.3], (t, 1)), hinge_axes=np.array([[0, 0, 0], [0, -1.0, 0]]),
        loop=True, label="root/test", character="humanoid", source="unit", license="MIT",
    )
    fields.update(changes)
    return Clip(**fields)


def test_save_load_roundtrip(tmp_path, walk_clip):
    path = walk_clip.save(tmp_path / "sub" / "walk.npz")
    back = load_clip(path)
    assert back.joint_names == walk_clip.joint_names and back.joint_types == walk_clip.joint_types
    assert back.fps == walk_clip.fps and back.loop and back.label == "root/locomotion/walk/forward"
    np.testing.assert_array_equal(back.joint_qpos, walk_clip.joint_qpos)
    np.testing.assert_array_equal(back.root_quat, walk_clip.root_quat)
    assert back.duration_s == pytest.approx((walk_clip.num_frames - 1) / walk_clip.fps)


def test_joint_slices_follow_types():
    c = tiny_clip()
    assert c.joint_slices() == [slice(0, 4), slice(4, 5)]


@pytest.mark.parametrize("changes, words", [
    (dict(root_quat=np.tile([2.0, 0, 0, 0], (3, 1))), "not unit"),
    (dict(joint_qpos=np.tile([1.0, 0, 0, 0, np.nan], (3, 1))), "NaN"),
    (dict(joint_qpos=np.zeros((3, 4))), "shape"),
    (dict(joint_types=("ball", "slider")), "joint types"),
    (dict(fps=0.0), "fps"),
])
def test_invalid_clips_are_refused(changes, words):
    with pytest.raises(ClipError, match=words):
        tiny_clip(**changes)


def test_load_rejects_other_files(tmp_path):
    bad = tmp_path / "x.npz"
    np.savez(bad, a=np.zeros(3))
    with pytest.raises(ClipError, match="x.npz"):
        load_clip(bad)
