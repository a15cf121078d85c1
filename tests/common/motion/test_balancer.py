"""The motion balancer's per-clip probabilities (UniCon 2020, Sec. 5.1, Eq. 8)."""

from fractions import Fraction as F

import numpy as np
import pytest
from scipy import stats

from common.motion.balancer import MotionBalancer, load_clip_labels


def test_small_tree_exact():
    b = MotionBalancer([
        ("c1", "a/x"),
        ("c2", "a/y"),
        ("c3", "a/y"),  # shares its leaf with c2
        ("c4", "b"),
        ("c5", "a/x/deep"),  # c1 sits on an inner node: "." and "deep" split x's share
    ])
    assert b.exact_probabilities == {"c1": F(1, 8), "c2": F(1, 8), "c3": F(1, 8), "c4": F(1, 2), "c5": F(1, 8)}
    np.testing.assert_allclose(b.probabilities, [1 / 8, 1 / 8, 1 / 8, 1 / 2, 1 / 8])


def test_repository_clips_exact():
    clips = [c for c in load_clip_labels() if not c[0].startswith("humanoid/bandai/")]  # those: test_bandai.py
    b = MotionBalancer(clips)
    p = b.exact_probabilities
    assert len(p) == len(clips) == 32
    assert sum(p.values()) == 1
    # root has 7 classes; martial_arts -> kick/punch; kick -> front (3 clips)/spin; a label
    # shared by a clip and its cross-skeleton copy on the humanoid splits its leaf
    assert p["humanoid3d_getup_faceup"] == F(1, 7)
    assert p["mass/balance"] == p["humanoid/mass_balance"] == F(1, 14)
    assert p["humanoid3d_punch"] == F(1, 14)
    assert p["humanoid3d_kick"] == p["mass/kick"] == p["humanoid/mass_kick"] == F(1, 84)
    assert p["humanoid3d_spinkick"] == F(1, 28)
    # locomotion -> crawl/run/walk; walk/forward holds 3 clips and the style/zombie sub-class
    assert p["humanoid3d_crawl"] == F(1, 21)
    assert p["humanoid3d_zombie_walk"] == F(1, 42)
    assert p["humanoid3d_walk"] == p["mass/walk"] == p["humanoid/mass_walk"] == F(1, 126)


def test_draws_follow_the_probabilities():
    b = MotionBalancer(load_clip_labels())
    ids = b.draw(np.random.default_rng(0), 20000)
    counts = np.array([ids.count(c) for c in b.clip_ids])
    assert stats.chisquare(counts, b.probabilities * len(ids)).pvalue > 0.01
    # Drawing clips uniformly (the unbalanced baseline) would look different.
    assert stats.chisquare(counts, np.full(len(counts), len(ids) / len(counts))).pvalue < 1e-6


@pytest.mark.parametrize("clips,match", [
    ([], "at least one"),
    ([("a", "root/x"), ("a", "root/y")], "repeat"),
    ([("a", "///")], "label"),
])
def test_bad_clip_lists_are_refused(clips, match):
    with pytest.raises(ValueError, match=match):
        MotionBalancer(clips)
