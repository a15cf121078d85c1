import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from common.motion.bvh import parse_bvh
from common.motion.errors import ClipError
from common.motion.import_bvh import BVH_TO_MUJOCO, CMU_TO_BIPED, biped_skeleton, bvh_to_clip, load_bvh
from common.motion.manifest import load_manifest

from .conftest import CMU, MASS

MASS_ENTRIES = [e for e in load_manifest().entries if e.format == "bvh" and e.character == "biped"]


def test_manifest_lists_8_mass_clips():
    assert len(MASS_ENTRIES) == 8


@pytest.mark.parametrize("entry", MASS_ENTRIES, ids=lambda e: e.id)
def test_every_mass_clip_imports_onto_the_biped(entry):
    clip = load_bvh(MASS / entry.path.split("/")[-1], label=entry.label)
    assert clip.character == "biped" and clip.num_frames == entry.frames
    assert clip.fps == pytest.approx(120.0, rel=1e-3)
    assert len(clip.joint_names) == 18  # 19 segments: 18 joints below the root
    assert clip.joint_types.count("hinge") == 4  # knees and elbows
    assert 0.7 < np.median(clip.root_pos[:, 2]) < 1.2  # metres, Z up


def test_mass_walk_walks_forward_along_x():
    clip = load_bvh(MASS / "walk.bvh")
    d = clip.root_pos[-1] - clip.root_pos[0]
    assert d[0] > 1.0 and abs(d[1]) < 0.2  # the biped faces +x (characters/presets/biped.py)


def test_axes_match_the_biped_preset():
    from common.characters.presets.biped import MASS_TO_MUJOCO

    np.testing.assert_array_equal(BVH_TO_MUJOCO, MASS_TO_MUJOCO)


def test_cmu_imports_and_maps_by_name():
    bvh = parse_bvh(CMU)
    assert len(bvh.joint_names) == 31 and bvh.num_frames == 2752
    clip = load_bvh(CMU, skeleton="cmu")
    assert clip.num_frames == 2752
    _, joints, _ = biped_skeleton()
    assert set(CMU_TO_BIPED) - {"Pelvis"} == {j.name for j in joints}
    # CMU units x 0.056444 -> a pelvis about a metre high
    assert 0.8 < np.median(clip.root_pos[:, 2]) < 1.2


def test_unknown_joint_in_name_map(tmp_path):
    root, joints, _ = biped_skeleton()
    with pytest.raises(ClipError, match="NoSuchJoint"):
        bvh_to_clip(parse_bvh(CMU), root=root, joints=joints, name_map={"Pelvis": "Hips", "FemurR": "NoSuchJoint"},
                    scale_m=0.056, character="biped", name="x")
    with pytest.raises(ClipError, match="Tail"):
        bvh_to_clip(parse_bvh(CMU), root=root, joints=joints, name_map={"Pelvis": "Hips", "Tail": "Hips"},
                    scale_m=0.056, character="biped", name="x")


HEADER = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition %s
  JOINT Leg
  {
    OFFSET 0 -40 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site
    {
      OFFSET 0 -40 0
    }
  }
}
MOTION
Frames: %d
Frame Time: 0.0333333
"""


def write_bvh(tmp_path, lines, order="Zrotation Xrotation Yrotation", frames=None):
    path = tmp_path / "t.bvh"
    path.write_text(HEADER % (order, len(lines) if frames is None else frames) + "\n".join(lines) + "\n")
    return path


def test_any_channel_order(tmp_path):
    values = "1 100 2 10 20 30 5 6 7"
    for order, seq in (("Zrotation Xrotation Yrotation", "ZXY"), ("Xrotation Yrotation Zrotation", "XYZ"),
                       ("Yrotation Zrotation Xrotation", "YZX")):
        bvh = parse_bvh(write_bvh(tmp_path, [values], order))
        expected = Rotation.from_euler(seq, [10, 20, 30], degrees=True)
        assert (bvh.local_rotations("Hips")[0] * expected.inv()).magnitude() < 1e-9
        np.testing.assert_allclose(bvh.root_positions()[0], [1, 100, 2])
    leg = parse_bvh(write_bvh(tmp_path, [values])).local_rotations("Leg")[0]
    assert (leg * Rotation.from_euler("XYZ", [5, 6, 7], degrees=True).inv()).magnitude() < 1e-9


@pytest.mark.parametrize("lines, frames, order, words", [
    (["0 0 0 0 0 0 0 0 0"], 2, None, r"truncated.*Frames: 2.*1 frame"),
    (["0 0 0 0 0 0 0 0"], None, None, r"frame 0.*8 values, expected 9"),
    (["0 0 0 0 nan 0 0 0 0"], None, None, r"frame 0.*Hips\.Xrotation"),
    (["0 0 0 0 abc 0 0 0 0"], None, None, r"frame 0.*'abc'"),
    (["0 0 0 0 0 0 0 0 0"], None, "Zrotation Xrotation", r"Hips.*declares 6 channels but found 5"),
    (["0 0 0 0 0 0 0 0 0"], None, "Zrotation Xrotation Wrotation", r"Hips.*Wrotation"),
])
def test_malformed_bvh_fails_clearly(tmp_path, lines, frames, order, words):
    path = write_bvh(tmp_path, lines, order or "Zrotation Xrotation Yrotation", frames)
    with pytest.raises(ClipError, match=words) as info:
        parse_bvh(path)
    assert "t.bvh" in str(info.value)


def test_missing_motion_section(tmp_path):
    path = tmp_path / "h.bvh"
    path.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 0\n}\n")
    with pytest.raises(ClipError, match="MOTION"):
        parse_bvh(path)
