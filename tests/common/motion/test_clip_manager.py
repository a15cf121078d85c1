"""`ClipManager`: the one place clip and start draws come from (UniCon 2020, Sec. 5.1)."""

import numpy as np
import pytest

from common.motion.balancer import MotionBalancer, load_clip_labels
from common.motion.clip_manager import ClipManager

CLIPS = [("easy", "root/a"), ("hard", "root/b/x"), ("other", "root/b/y")]
DURATION = {"easy": 2.0, "hard": 0.05, "other": 4.0}


def test_draws_are_the_balancers_and_a_uniform_start_with_the_same_random_numbers():
    m = ClipManager(CLIPS, duration_s=DURATION.__getitem__)
    np.testing.assert_allclose(m.probabilities, MotionBalancer(CLIPS).probabilities)
    assert m.draw_clips(np.random.default_rng(5), 40) == MotionBalancer(CLIPS).draw(np.random.default_rng(5), 40)
    a, b = np.random.default_rng(1), np.random.default_rng(1)
    for _ in range(20):
        clip, start = m.draw(a, min_left_s=0.1)
        expected = m.clip_ids[int(b.choice(3, p=m.probabilities))]
        assert clip == expected
        assert start == float(b.uniform(0.0, max(0.0, DURATION[clip] - 0.1)))
    assert m.draw_start(np.random.default_rng(0), "hard", min_left_s=0.1) == 0.0  # shorter than the margin


def test_reweight_and_given_probabilities():
    m = ClipManager(CLIPS, weights=np.array([0.1, 1.0, 1.0]))
    np.testing.assert_allclose(m.draw_probabilities, np.array([0.05, 0.25, 0.25]) / 0.55)
    np.testing.assert_allclose(m.probabilities, [0.5, 0.25, 0.25])
    with pytest.raises(ValueError, match="positive and finite"):
        m.reweight(np.array([1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match="without clip durations"):
        m.draw(np.random.default_rng(0))
    u = ClipManager.with_probabilities(["a", "b"], np.full(2, 0.5))
    assert u.clip_ids == ("a", "b") and u.draw_clip(np.random.default_rng(0)) in ("a", "b")
    with pytest.raises(ValueError, match="one per clip"):
        ClipManager.with_probabilities(["a", "b"], np.ones(3))
    assert len(ClipManager(load_clip_labels()).table().splitlines()) == len(load_clip_labels())  # a line per clip
