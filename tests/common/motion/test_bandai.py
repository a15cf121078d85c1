"""Issue 52 item 5: the Bandai Namco takes (22 joints, rotated rest frames) retargeted onto the
DeepMimic humanoid, labelled content -> style, split by takes, shipped as npz."""

import dataclasses
import json
import shutil

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from learner.commands import motion as cli
from common.motion.balancer import MotionBalancer
from common.motion.bandai import ID_PREFIX, find_takes, import_bandai
from common.motion.bvh import parse_bvh
from common.motion.check import check_motion
from common.motion.cross_skeleton import SOURCE_SKELETONS, guess_skeleton, map_pose, rest_corrections, source_pose, standing_rest
from common.motion.import_bvh import BVH_TO_MUJOCO
from common.motion.library import MotionLibrary, clips_for
from common.motion.manifest import Manifest, load_manifest, unicon_take_split
from common.motion.reference import CharacterMotion
from common.motion.root_height import foot_heights

from .conftest import DATA, base_character

SAMPLES = DATA / "mocap" / "bandai_namco"
WALK = SAMPLES / "dataset-1_walk_normal_001.bvh"
RAISE = SAMPLES / "dataset-2_raise-up-right-hand_normal_001.bvh"
SKEL = SOURCE_SKELETONS["bandai"]
LIMBS = ("right_hip", "right_knee", "left_hip", "left_knee", "right_shoulder", "right_elbow", "left_shoulder", "left_elbow")


def humanoid():
    return base_character("humanoid")


def qpos_of(clip):
    return CharacterMotion.from_clip(clip, humanoid().model).qpos_frames


def bone_angles_deg(clip, pose, frames):
    """(len(frames), len(LIMBS)) angle between each humanoid limb bone and its source bone."""
    m = humanoid().model
    d = mujoco.MjData(m)
    q = qpos_of(clip)
    out = np.zeros((len(frames), len(LIMBS)))
    for i, k in enumerate(frames):
        d.qpos[:] = q[k]
        mujoco.mj_kinematics(m, d)
        for j, body in enumerate(LIMBS):
            seg = SKEL.segments[body]
            (a, b), (ta, tb) = seg.source_dirs[0], seg.target_dirs[0]
            want = pose.positions[k, pose.names.index(b)] - pose.positions[k, pose.names.index(a)]
            got = d.xpos[m.body(tb).id] - d.xpos[m.body(ta).id]
            c = want @ got / np.linalg.norm(want) / np.linalg.norm(got)
            out[i, j] = np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
    return out


def test_the_skeleton_is_guessed_and_its_rest_pose_is_not_a_standing_pose():
    assert guess_skeleton(WALK) == "bandai"
    bvh = parse_bvh(WALK)
    pose = source_pose(bvh, SKEL.scale_m)
    # With every rotation 0 the thighs lie sideways (rotated rest frames): a hip height at rest is meaningless...
    thigh = pose.at_rest("LowerLeg_L") - pose.at_rest("UpperLeg_L")
    assert abs(thigh[2]) < 0.01 * np.linalg.norm(thigh)
    # ...so it is measured with each bone turned onto the humanoid's rest direction: legs straight down.
    stand = standing_rest(bvh, pose, SKEL, rest_corrections(SKEL, pose))
    i = pose.names.index
    for side in "LR":
        leg = stand[i(f"Foot_{side}")] - stand[i(f"UpperLeg_{side}")]
        assert leg[2] < -0.99 * np.linalg.norm(leg)
    hip = stand[[i("UpperLeg_L"), i("UpperLeg_R")], 2].mean() - min(stand[i(f), 2] for f in SKEL.feet)
    assert 0.8 < hip < 0.95  # thigh 39 cm + shin 41 cm + the toe joint 7.5 cm below the ankle


def test_rest_corrections_take_source_bones_at_rest_onto_the_humanoid_rest_bones():
    pose = source_pose(parse_bvh(WALK), SKEL.scale_m)
    ch = humanoid()
    d = mujoco.MjData(ch.model)
    mujoco.mj_kinematics(ch.model, d)
    rest = {ch.model.body(b).name: d.xpos[b] for b in range(1, ch.model.nbody)}
    corr = rest_corrections(SKEL, pose)
    assert set(corr) == set(SKEL.segments) and len(corr) == 13
    for body, seg in SKEL.segments.items():
        src, dst = seg.source_dirs[0], seg.target_dirs[0]
        if len(src) != 2 or not isinstance(src[0], str) or isinstance(dst, str):
            continue
        d_s = pose.at_rest(src[1]) - pose.at_rest(src[0])
        d_h = rest[dst[1]] - rest[dst[0]]
        np.testing.assert_allclose(corr[body].apply(d_s / np.linalg.norm(d_s)), d_h / np.linalg.norm(d_h), atol=1e-9)


@pytest.mark.filterwarnings("ignore:Gimbal lock")
def test_a_source_pose_with_every_segment_at_its_correction_gives_the_humanoid_rest():
    """Frame 0 is built so that every mapped source joint's global rotation is its rest
    correction C_b (its bones along the humanoid's rest bones): the humanoid comes out at its
    rest pose, every ball joint and hinge near 0, through the file's Euler channels."""
    bvh = parse_bvh(RAISE)
    pose = source_pose(bvh, SKEL.scale_m)
    corr = rest_corrections(SKEL, pose)
    m = Rotation.from_matrix(BVH_TO_MUJOCO)
    turn = {seg.source: m.inv() * corr[body] * m for body, seg in SKEL.segments.items()}  # in file axes
    motion = bvh.motion[:1].copy()
    glob = {}
    for name, p in zip(bvh.joint_names, bvh.parents):
        parent = glob[bvh.joint_names[p]] if p >= 0 else Rotation.identity()
        glob[name] = turn.get(name, parent)
        cols = bvh.columns(name)
        motion[0, [cols["Zrotation"], cols["Xrotation"], cols["Yrotation"]]] = (parent.inv() * glob[name]).as_euler("ZXY", degrees=True)
    clip = map_pose(dataclasses.replace(bvh, motion=motion), "bandai")
    for name, sl, kind in zip(clip.joint_names, clip.joint_slices(), clip.joint_types):
        q = clip.joint_qpos[0, sl]
        angle = Rotation.from_quat(q, scalar_first=True).magnitude() if kind == "ball" else abs(q[0])
        assert np.degrees(angle) < 1.0, (name, np.degrees(angle))


def test_a_standing_frame_comes_out_upright_with_flat_feet():
    clip = map_pose(parse_bvh(RAISE), "bandai")
    m = humanoid().model
    d = mujoco.MjData(m)
    d.qpos[:] = qpos_of(clip)[0]
    mujoco.mj_kinematics(m, d)
    for body in ("root", "chest", "left_ankle", "right_ankle"):
        up = Rotation.from_quat(d.xquat[m.body(body).id], scalar_first=True).apply([0.0, 0.0, 1.0])
        assert np.degrees(np.arccos(up[2])) < 8.0, body


def test_a_walk_keeps_its_feet_on_the_floor_and_its_bone_directions():
    bvh = parse_bvh(WALK)
    clip = map_pose(bvh, "bandai")
    from common.motion.cross_skeleton import plant_feet

    planted = plant_feet(clip)
    h, _ = foot_heights(humanoid().model, qpos_of(planted), tuple(humanoid().foot_geoms))
    lower = h.min(axis=1)
    assert lower.min() > -0.01 and np.mean(lower) < 0.01  # the lower foot on the floor throughout
    assert 0.4 < min(planted.extra["contact_frac"]) < 0.7  # each foot in stance about half the time
    angles = bone_angles_deg(planted, source_pose(bvh, SKEL.scale_m), range(0, bvh.num_frames, 5))
    assert angles.mean() < 2.0 and angles.max() < 10.0, angles.max(axis=0)


def test_every_sample_take_imports_and_a_mislabelled_take_fails_naming_it(tmp_path):
    contents = ["walk", "raise-up-right-hand"]
    for dataset, bvh, content in (("dataset-1", WALK, 0), ("dataset-2-pool", RAISE, 1), ("dataset-1", WALK, 1)):
        (tmp_path / dataset / "data").mkdir(parents=True, exist_ok=True)
        (tmp_path / dataset / "cfg").mkdir(exist_ok=True)
        prefix = bvh.stem.split("_")[0]
        (tmp_path / dataset / "cfg" / "content_label.txt").write_text("".join(f"{prefix}_{c}\n" for c in contents))
        (tmp_path / dataset / "cfg" / "style_label.txt").write_text(f"{prefix}_normal\n")
        stem = bvh.stem if content == contents.index(bvh.stem.split("_")[1]) else bvh.stem.replace("walk", "run")
        shutil.copy(bvh, tmp_path / dataset / "data" / f"{stem}.bvh")
        (tmp_path / dataset / "data" / f"{stem}.json").write_text(json.dumps({"content": content, "style": 0}))
    manifest = tmp_path / "clips.json"
    manifest.write_text(json.dumps({"clips": [{"id": "keep", "label": "root/x"}]}))
    ticks = []

    class Bar:  # what `learner.progress.Progress` offers the conversion
        def __init__(self, n):
            ticks.append(("total", n))

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return None

        def update(self):
            ticks.append("take")

    clips, failures = import_bandai(tmp_path, tmp_path / "out", manifest, log=lambda *_: None, bar_for=Bar)
    assert ticks == [("total", 2), "take", "take"]  # each take found advances the bar (the mislabelled one fails when found)
    assert sorted(c.name for c in clips) == sorted(ID_PREFIX + b.stem for b in (WALK, RAISE))
    assert len(failures) == 1 and failures[0][0].name == "dataset-1_run_normal_001.bvh"
    assert "file name says ['run', 'normal']" in failures[0][1]
    entries = json.loads(manifest.read_text())["clips"]
    assert [e["id"] for e in entries] == ["keep", ID_PREFIX + WALK.stem, ID_PREFIX + RAISE.stem]
    assert entries[1]["label"] == "root/bandai/walk/normal" and entries[1]["format"] == "npz"
    walk = next(c for c in clips if c.name.endswith(WALK.stem))
    stored = tmp_path / "out" / f"{ID_PREFIX}{WALK.stem}.npz"
    full = walk.save(tmp_path / "full.npz")
    assert stored.stat().st_size < 0.6 * full.stat().st_size  # float32, compressed: about half the float64 file


def test_the_cli_flag_runs_the_conversion(monkeypatch, tmp_path):
    seen = []
    import common.motion.bandai as bandai

    monkeypatch.setattr(bandai, "import_bandai", lambda root, out, bar_for: seen.append((root, out, bar_for(3))) or ([], []))
    assert cli.main(["import", "--bandai", str(tmp_path)]) == 0 and seen[0][:2] == (str(tmp_path), None)
    assert type(seen[0][2]).__name__ == "Progress"  # the command's progress bar


@pytest.fixture(scope="module")
def bandai_entries():
    return [e for e in load_manifest().entries if e.id.startswith(ID_PREFIX)]


def test_the_library_holds_454_bandai_takes_labelled_content_then_style(bandai_entries):
    assert len(bandai_entries) == 454
    ids = {c for c, _ in clips_for("humanoid")}
    assert {e.id for e in bandai_entries} <= ids and len(ids) == 24 + 454
    for e in bandai_entries:
        _, source, content, style = e.label_parts
        assert source == "bandai" and e.id.split("/")[-1].split("_")[1:3] == [content, style]
        assert e.character == "humanoid" and e.format == "npz" and e.retarget_from is None
    # The balancer: one `bandai` node beside the other top classes, contents equal below it, styles within.
    top = {e.label_parts[1] for e in load_manifest().entries if e.character == "humanoid"}
    bal = MotionBalancer([(e.id, e.label) for e in load_manifest().entries if e.character == "humanoid"])
    p = dict(zip(bal.clip_ids, bal.probabilities))
    assert sum(p[e.id] for e in bandai_entries) == pytest.approx(1.0 / len(top))
    contents = {e.label_parts[2] for e in bandai_entries}
    walk = [e.id for e in bandai_entries if e.label_parts[2] == "walk"]
    assert sum(p[c] for c in walk) == pytest.approx(1.0 / len(top) / len(contents))


def test_the_shipped_takes_load_and_stay_on_the_floor(bandai_entries):
    """Every shipped take loads as a humanoid clip; over the library the lower foot never goes
    more than 2 cm below the floor and the share of (frame, DOF) pairs outside the humanoid's
    joint / PD target ranges stays under 1 % (0.23 % measured over all 454 takes)."""
    lib = MotionLibrary()
    ch = humanoid()
    feet = tuple(ch.foot_geoms)
    outside, total = 0, 0
    for e in bandai_entries[::9]:
        clip = lib.clip(e.id)
        assert clip.character == "humanoid" and clip.num_frames == e.frames and clip.label == e.label
        assert clip.extra["retarget_from"] == "bandai" and clip.license.startswith("CC BY-NC 4.0")
        report = check_motion(CharacterMotion.from_clip(clip, ch.model), feet)
        assert report.penetration_m < 0.02, e.id
        outside += report.limit_violations
        total += clip.num_frames * 28  # the humanoid's 28 ranged DOFs (check._dof_ranges)
    assert outside / total < 0.01


def test_the_take_split_puts_single_takes_in_test_and_one_of_each_pair_with_more(bandai_entries):
    split = unicon_take_split(Manifest(tuple(bandai_entries)), seed=0)
    assert split == unicon_take_split(Manifest(tuple(bandai_entries)), seed=0)
    test = set(split.test)
    by_label = {}
    for e in bandai_entries:
        by_label.setdefault(e.label, []).append(e.id)
    for label, ids in by_label.items():
        held = sum(i in test for i in ids)
        if len(ids) == 1:
            assert held == 1, label
        else:
            assert held == max(1, round(0.2 * len(ids))) and held < len(ids), label
    assert len(split.train) + len(split.test) == 454
    assert set(split.test) != set(unicon_take_split(Manifest(tuple(bandai_entries)), seed=1).test)
