import json

import pytest

from common.motion.errors import ClipError
from common.motion.manifest import load_manifest, unicon_split


def test_manifest_has_all_clips_and_a_label_tree():
    m = load_manifest()
    assert len(m.entries) == 32 + 454  # 16 DeepMimic, 8 MASS on the biped, the same 8 on the humanoid, 454 Bandai Namco
    assert sum(e.character == "humanoid" for e in m.entries) == 24 + 454
    assert [e.id for e in m.entries if e.retarget_from == "mass"] == [
        f"humanoid/mass_{n}" for n in ("backflip", "balance", "cart", "dance", "kick", "pirouette", "run", "walk")]
    tree = m.label_tree()
    assert set(tree) == {"root"}
    assert "humanoid3d_walk" in tree["root"]["locomotion"]["walk"]["forward"]["_clips"]
    assert "humanoid3d_zombie_walk" in tree["root"]["locomotion"]["walk"]["forward"]["style"]["zombie"]["_clips"]


def test_split_is_80_20_of_frames_and_reproducible():
    m = load_manifest()
    a, b = unicon_split(m, seed=3), unicon_split(m, seed=3)
    assert a == b
    assert set(a.train) | set(a.test) == {e.id for e in m.entries} and not set(a.train) & set(a.test)
    seconds = sum(m.by_id(i).frames / m.by_id(i).fps for i in a.test) / sum(e.frames / e.fps for e in m.entries)
    assert seconds == pytest.approx(a.test_fraction_frames) and abs(seconds - 0.2) < 0.05


def test_split_counts_frames_at_one_rate(tmp_path):
    """A 120 Hz clip weighs as much as a 30 Hz clip of the same length, not four times more."""
    clips = [dict(entry(i, f"root/c{i}", 30 * (i + 1)), fps=30.0) for i in range(4)]
    clips += [dict(entry(9, "root/c9", 120 * 3), fps=120.0)]  # 3 s at 120 Hz
    m = write_manifest(tmp_path, clips)  # 1 + 2 + 3 + 4 + 3 = 13 s; 20% = 2.6 s
    split = unicon_split(m, seed=0)
    assert split.test_fraction_frames == pytest.approx(3.0 / 13.0)
    assert "c9" not in split.test or "c2" not in split.test  # one 3-s clip, never both


def write_manifest(tmp_path, clips):
    path = tmp_path / "clips.json"
    path.write_text(json.dumps({"clips": clips}))
    return load_manifest(path)


def entry(i, label, frames):
    return dict(id=f"c{i}", path=f"c{i}.txt", label=label, format="deepmimic_json", fps=30.0, frames=frames)


def test_rarest_classes_go_to_test_first(tmp_path):
    clips = [entry(i, "root/walk", 100) for i in range(8)] + [entry(10, "root/flip", 50), entry(11, "root/roll", 60),
                                                              entry(12, "root/crawl", 120)]
    m = write_manifest(tmp_path, clips)  # 1030 frames; 20% = 206
    split = unicon_split(m, seed=0)
    assert {"c10", "c11"} <= set(split.test)  # the two rarest classes
    assert all(f"c{i}" in split.train for i in range(8)) or "c12" in split.train
    # seeds decide ties between equally rare classes
    tied = write_manifest(tmp_path, [entry(i, f"root/k{i}", 10) for i in range(10)])
    tests = {unicon_split(tied, seed=s).test for s in range(6)}
    assert len(tests) > 1 and all(len(t) == 2 for t in tests)


def test_bad_manifest(tmp_path):
    with pytest.raises(ClipError, match="label"):
        write_manifest(tmp_path, [dict(id="a", path="a", format="bvh", fps=1, frames=2)])
