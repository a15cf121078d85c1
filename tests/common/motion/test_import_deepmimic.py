import json

import numpy as np
import pytest

from common.motion import quat
from common.motion.errors import ClipError
from common.motion.import_deepmimic import FRAME_WIDTH, load_deepmimic
from common.motion.manifest import load_manifest

from .conftest import DEEPMIMIC


def deepmimic_entries():
    return [e for e in load_manifest().entries if e.format == "deepmimic_json"]


def test_manifest_lists_16_deepmimic_clips():
    assert len(deepmimic_entries()) == 16


@pytest.mark.parametrize("entry", deepmimic_entries(), ids=lambda e: e.id)
def test_every_deepmimic_clip_imports(entry):
    clip = load_deepmimic(DEEPMIMIC / entry.path.split("/")[-1], label=entry.label)
    assert clip.fps == pytest.approx(entry.fps, rel=2e-3)
    assert clip.num_frames == pytest.approx(entry.frames, abs=1)
    assert clip.loop == entry.loop
    for sl, kind in zip(clip.joint_slices(), clip.joint_types):
        if kind == "ball":
            np.testing.assert_allclose(np.linalg.norm(clip.joint_qpos[:, sl], axis=1), 1.0, atol=1e-9)
    # Z up: a standing or walking pelvis is well above the floor at the start.
    if entry.label.startswith(("root/locomotion/walk", "root/locomotion/run")):
        assert 0.6 < clip.root_pos[0, 2] < 1.0


def write(tmp_path, frames, loop="wrap"):
    path = tmp_path / "m.txt"
    path.write_text(json.dumps({"Loop": loop, "Frames": frames}))
    return path


def frame(dt=0.1, x=0.0):
    row = [dt, x, 0.85, 0.0, 1.0, 0, 0, 0]
    for kind in ("b", "b", "b", "h", "b", "b", "h", "b", "h", "b", "b", "h"):
        row += [1.0, 0, 0, 0] if kind == "b" else [0.0]
    assert len(row) == FRAME_WIDTH
    return row


def test_axes_change_and_normalization(tmp_path):
    rows = [frame(), frame(0.0)]
    rows[0][1:4] = [0.1, 0.9, 0.2]          # Y up position
    rows[0][4:8] = [2.0, 0.0, 2.0, 0.0]      # unnormalized yaw about Y up
    clip = load_deepmimic(write(tmp_path, rows))
    np.testing.assert_allclose(clip.root_pos[0], [0.1, -0.2, 0.9])
    # a turn about Y (up) becomes a turn about Z (up), unit length
    np.testing.assert_allclose(clip.root_quat[0], [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-12)


def test_resampled_by_time(tmp_path):
    # 3 frames at uneven times 0, 0.1, 0.3 s (last dt 0): position x = 0, 1, 3 -> linear in time.
    rows = [frame(0.1, 0.0), frame(0.2, 1.0), frame(0.0, 3.0)]
    clip = load_deepmimic(write(tmp_path, rows), fps=20.0)
    assert clip.num_frames == 7 and clip.fps == pytest.approx(20.0)
    np.testing.assert_allclose(clip.root_pos[:, 0], [0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0])


def test_normalizes_real_unnormalized_clip():
    raw = np.array(json.loads((DEEPMIMIC / "humanoid3d_kick.txt").read_text())["Frames"])
    hip_cols = slice(16, 20)  # right_hip (w, x, y, z) in the file
    assert np.abs(np.linalg.norm(raw[:, hip_cols], axis=1) - 1).max() > 0.4  # the file really is off
    clip = load_deepmimic(DEEPMIMIC / "humanoid3d_kick.txt")
    sl = clip.joint_slices()[clip.joint_names.index("right_hip")]
    np.testing.assert_allclose(np.linalg.norm(clip.joint_qpos[:, sl], axis=1), 1.0, atol=1e-9)


@pytest.mark.parametrize("mutate, words", [
    (lambda rows: rows[1].pop(), r"frame 1.*expected 44"),
    (lambda rows: rows[1].__setitem__(9, float("nan")), r"frame 1.*chest\.x"),
    (lambda rows: rows[0].__setitem__(0, 0.0), r"frame 0.*dt"),
    (lambda rows: rows[1].__setitem__(4, 0.0) or rows[1].__setitem__(5, 0.0), r"frame 1.*zero-length"),
])
def test_malformed_files_fail_clearly(tmp_path, mutate, words):
    rows = [frame(), frame(), frame(0.0)]
    mutate(rows)
    path = tmp_path / "bad.txt"
    path.write_text(json.dumps({"Loop": "wrap", "Frames": rows}))  # json writes NaN as NaN
    with pytest.raises(ClipError, match=words) as info:
        load_deepmimic(path)
    assert "bad.txt" in str(info.value)


def test_bad_loop_flag_and_not_json(tmp_path):
    with pytest.raises(ClipError, match="Loop"):
        load_deepmimic(write(tmp_path, [frame(), frame(0.0)], loop="forever"))
    bad = tmp_path / "trunc.txt"
    bad.write_text('{"Loop": "wrap", "Frames": [[0.1, 1, 2')
    with pytest.raises(ClipError, match="trunc.txt"):
        load_deepmimic(bad)


def test_hinge_axis_is_minus_y():
    clip = load_deepmimic(DEEPMIMIC / "humanoid3d_walk.txt")
    knee = clip.joint_names.index("right_knee")
    np.testing.assert_array_equal(clip.hinge_axes[knee], [0, -1, 0])
    assert quat.y_up_to_z_up_pos(np.array([0, 0, 1.0])).tolist() == [0, -1, 0]
