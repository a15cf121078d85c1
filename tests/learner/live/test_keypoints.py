"""Real keypoints in (issue 53 item 3): a 16-marker MJCF keyframe file (mocap `mpos` at 30 fps,
made here from the walk clip's bodies) converted by `morphmimic keypoints convert` with the
shipped `markers16` mapping; the video scheduler's IK reproduces the clip's body positions from
it; `send-poses` refuses the raw file and a 16-joint array before sending and sends the converted
one, which the receiver accepts whole."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest

from common.characters import load_character
from common.motion.library import MotionLibrary
from common.motion.reference import CharacterMotion
from common.tasks.executor.schedulers.pose_ik import PositionIK
from common.tasks.executor.schedulers.pose_packet import HUMANOID_JOINTS
from learner.live import keypoints, pose_sender

ORDER = ("pelvis", "head", "left_toe", "right_toe", "left_heel", "right_heel", "left_knee", "right_knee",
         "left_hand", "right_hand", "left_elbow", "right_elbow", "left_shoulder", "right_shoulder", "left_hip", "right_hip")
FPS = 30.0
IK_MEAN_TOLERANCE_M = 0.03
"""Mean body-position error of the IK's pose against the clip's (measured: 1.1 cm; the ankles,
made from heel and toe, 4.3 cm)."""
IK_JOINT_TOLERANCE_M = 0.06


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return load_character("humanoid").model


@pytest.fixture(scope="module")
def walk(model) -> tuple[np.ndarray, np.ndarray]:
    """(16 markers [T, 16, 3] in ORDER, the bodies' true origins [T, 15, 3]) of the walk at 30 fps."""
    motion = CharacterMotion.from_clip(MotionLibrary().clip("humanoid3d_walk"), model)
    data = mujoco.MjData(model)
    markers, truth = [], []
    for k in range(int(motion.duration_s * FPS)):
        data.qpos[:] = motion.qpos(k / FPS)
        mujoco.mj_kinematics(model, data)

        def at(body: str, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
            b = model.body(body).id
            return data.xpos[b] + data.xmat[b].reshape(3, 3) @ np.asarray(offset)
        m = {"pelvis": at("root"), "head": at("neck", (0, 0, 0.175))}
        for s in ("left", "right"):  # the toe and heel on the sole's ends, the others at the joints
            m |= {f"{s}_toe": at(f"{s}_ankle", (0.133, 0, -0.04)), f"{s}_heel": at(f"{s}_ankle", (-0.043, 0, -0.04)),
                  f"{s}_knee": at(f"{s}_knee"), f"{s}_hand": at(f"{s}_wrist"), f"{s}_elbow": at(f"{s}_elbow"),
                  f"{s}_shoulder": at(f"{s}_shoulder"), f"{s}_hip": at(f"{s}_hip")}
        markers.append([m[n] for n in ORDER])
        truth.append(data.xpos[1:].copy())
    return np.array(markers), np.array(truth)


def write_mjcf_markers(path, markers: np.ndarray, fps: float = FPS) -> None:
    """The markers as an MJCF file: one mocap body per marker, one <key mpos> per frame."""
    bodies = "\n".join(f'    <body name="{n}" mocap="true"><geom type="sphere" size="0.02" contype="0" conaffinity="0"/></body>'
                       for n in ORDER)
    keys = "\n".join(f'    <key time="{k / fps:.6f}" mpos="{" ".join(f"{v:.6f}" for v in frame.reshape(-1))}"/>'
                     for k, frame in enumerate(markers))
    path.write_text(f'<mujoco model="markers">\n  <worldbody>\n{bodies}\n  </worldbody>\n  <keyframe>\n{keys}\n  </keyframe>\n</mujoco>\n')


def test_convert_a_16_marker_mjcf_file_and_the_ik_reproduces_the_clip(model, walk, tmp_path, capsys) -> None:
    markers, truth = walk
    source, out = tmp_path / "markers.xml", tmp_path / "poses.npz"
    write_mjcf_markers(source, markers)
    assert keypoints.main(["convert", str(source), "--mapping", "markers16", "--out", str(out)]) == 0
    assert f"{len(markers)} frames of 16 points" in capsys.readouterr().out
    positions, names, fps = pose_sender.load_keypoints(out)
    assert names == HUMANOID_JOINTS and fps == pytest.approx(FPS) and positions.shape == (len(markers), 15, 3)
    direct = [HUMANOID_JOINTS.index(j) for j in ("root", "right_elbow", "left_knee", "right_hip", "left_shoulder")]
    np.testing.assert_allclose(positions[:, direct], truth[:, direct], atol=1e-5)  # renamed and reordered
    ik = PositionIK(model)
    data = mujoco.MjData(model)
    errors = []
    for frame, true in zip(positions, truth):
        data.qpos[:] = ik.solve(frame)
        mujoco.mj_kinematics(model, data)
        errors.append(np.linalg.norm(data.xpos[1:] - true, axis=1))
    errors = np.array(errors)
    assert errors.mean() < IK_MEAN_TOLERANCE_M and errors.mean(axis=0).max() < IK_JOINT_TOLERANCE_M, errors.mean(axis=0)


def test_array_sources_scale_y_up_and_bone_fitting(model, walk, tmp_path) -> None:
    markers, truth = walk
    mm_y_up = np.stack([markers[..., 0], markers[..., 2], -markers[..., 1]], axis=-1) * 1000.0
    np.save(tmp_path / "markers.npy", mm_y_up)
    mapping = json.loads((keypoints.MAPS / "markers16.json").read_text()) | {"scale": 0.001, "up": "y", "fit_bones": True}
    (tmp_path / "map.json").write_text(json.dumps(mapping))
    out = tmp_path / "fit.npz"
    assert keypoints.main(["convert", str(tmp_path / "markers.npy"), "--mapping", str(tmp_path / "map.json"), "--out", str(out)]) == 0
    positions, _, fps = pose_sender.load_keypoints(out)
    assert fps == 30.0  # from the mapping: an array does not say
    parents = np.array([model.body_parentid[b] - 1 for b in range(1, model.nbody)])
    bones = np.linalg.norm(positions[:, 1:] - positions[:, parents[1:]], axis=2)
    np.testing.assert_allclose(bones, np.broadcast_to(np.linalg.norm(model.body_pos[2:], axis=1), bones.shape), atol=1e-9)
    np.testing.assert_allclose(positions[:, 0], truth[:, 0], atol=1e-6)  # the root stays; z is up again


def test_bad_mappings_and_sources_are_one_line_exit_2(walk, tmp_path, capsys) -> None:
    np.save(tmp_path / "m.npy", walk[0])
    cases = [
        ({"joints": {"root": "pelvis"}}, "missing chest, neck"),
        ({**json.loads((keypoints.MAPS / "markers16.json").read_text()), "source": list(ORDER[:-1])}, "16 points per frame but 15 names"),
        ({**json.loads((keypoints.MAPS / "markers16.json").read_text()), "colour": 1}, "unknown keys colour"),
    ]
    for i, (mapping, message) in enumerate(cases):
        (tmp_path / f"{i}.json").write_text(json.dumps(mapping))
        with pytest.raises(SystemExit) as exit_info:
            keypoints.main(["convert", str(tmp_path / "m.npy"), "--mapping", str(tmp_path / f"{i}.json"), "--out", str(tmp_path / "o.npz")])
        err = capsys.readouterr().err.strip()
        assert exit_info.value.code == 2 and len(err.splitlines()) == 1 and message in err, err
    with pytest.raises(SystemExit):
        keypoints.main(["convert", str(tmp_path / "m.npy"), "--mapping", "no_such_map", "--out", str(tmp_path / "o.npz")])
    assert "markers16" in capsys.readouterr().err


def test_send_poses_refuses_a_raw_16_marker_file_and_sends_the_converted_one(walk, tmp_path, capsys) -> None:
    from common.tasks.executor.schedulers.video import VideoScheduler

    markers, _ = walk
    model = load_character("humanoid").model
    np.savez(tmp_path / "raw.npz", positions=markers, fps=np.array(FPS))
    write_mjcf_markers(tmp_path / "markers.xml", markers)
    with VideoScheduler(model, 1 / 30) as s:
        for raw in ("raw.npz", "markers.xml"):
            assert pose_sender.main([str(tmp_path / raw), "--port", str(s.port)]) == 2
            err = capsys.readouterr().err.strip()
            assert len(err.splitlines()) == 1 and "keypoints convert" in err, err
        assert "has 16 joints per frame; the video scheduler expects 15: root, chest, neck" in \
            (pose_sender.main([str(tmp_path / "raw.npz"), "--port", str(s.port)]), capsys.readouterr().err)[1]
        s.poll()
        assert s.received == 0 and not s.rejected  # refused before sending
        out = tmp_path / "poses.npz"
        assert keypoints.main(["convert", str(tmp_path / "markers.xml"), "--mapping", "markers16", "--out", str(out)]) == 0
        assert pose_sender.main([str(out), "--port", str(s.port), "--seconds", "0.5"]) == 0
        for _ in range(50):
            if s.poll() == 0 and s.received >= 16:
                break
        assert s.received == 16 and not s.rejected  # 0 .. 0.5 s at 30 fps
