import json

import pytest

from common.motion.errors import ClipError
from common.motion.manifest import load_manifest, unicon_split


def test_manifest_has_all_clips_and_a_label_tree():
    m = load_manifest()
    assert len(m.entries) == 24
    tree = m.label_tree()
    assert set(tree) == {"root"}
    assert "humanoid3d_walk" in tree["root"]["locomotion"]["walk"]["forward"]["_clips"]
    assert "humanoid3d_zombie_walk" in tree["root"]["locomotion"]["walk"]["forward"]["style"]["zombie"]["_clips"]


def test_split_is_80_20_of_frames_and_reproducible():
    m = load_manifest()
    a, b = unicon_split(m, seed=3), unicon_split(m, seed=3)
    assert a == b
    assert set(a.train) | set(a.test) == {e.id for e in m.entries} and not set(a.train) & set(a.test)
    frames = sum(m.by_id(i).frames for i in a.test) / m.total_frames
    assert frames == pytest.approx(a.test_fraction_frames) and abs(frames - 0.2) < 0.05


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
