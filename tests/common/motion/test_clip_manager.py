"""`ClipManager`: the one place clip and start draws come from (UniCon 2020, Sec. 5.1)."""

import numpy as np
import pytest

from common.motion.balancer import MotionBalancer, load_clip_labels
from common.motion.clip_manager import ClipManager, start_bins

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


def test_a_start_from_bin_weights_lands_in_the_drawn_bin_and_the_last_bin_ends_at_the_range():
    """`draw_start` with `bin_weights` (the sampler's failure-weighted starts): a bin by its
    weight, a uniform time inside it; bins of 0.5 s over `other` (4 s, 0.1 s kept at the end:
    [0, 3.9], 8 bins, the last 0.4 s long)."""
    m = ClipManager(CLIPS, duration_s=DURATION.__getitem__)
    assert start_bins(3.9, 0.5) == 8 and start_bins(4.0, 0.5) == 8 and start_bins(0.0, 0.5) == 1
    rng = np.random.default_rng(0)
    only = np.zeros(8)
    only[2] = 1.0
    starts = [m.draw_start(rng, "other", 0.1, only, 0.5) for _ in range(200)]
    assert all(1.0 <= t < 1.5 for t in starts)
    only[:] = 0.0
    only[7] = 1.0
    starts = [m.draw_start(rng, "other", 0.1, only, 0.5) for _ in range(200)]
    assert all(3.5 <= t <= 3.9 for t in starts) and max(starts) > 3.8  # the short last bin, all of it
    assert m.draw_start(rng, "hard", 0.1, np.ones(1), 0.5) == 0.0  # a clip shorter than the margin: bin 0, from 0
    # spread over the weights: bin 0 three times as often as bin 1
    two = ClipManager(CLIPS, duration_s={"easy": 1.0, "hard": 1.0, "other": 1.0}.__getitem__)
    starts = np.array([two.draw_start(rng, "easy", 0.0, np.array([3.0, 1.0]), 0.5) for _ in range(4000)])
    assert abs((starts < 0.5).mean() - 0.75) < 0.03


@pytest.mark.parametrize("weights", [np.ones(7), np.zeros(8), np.r_[np.ones(7), -1.0], np.r_[np.ones(7), np.nan]])
def test_bad_bin_weights_are_refused_with_what_is_allowed(weights):
    m = ClipManager(CLIPS, duration_s=DURATION.__getitem__)
    with pytest.raises(ValueError, match=r"expected 8 weights \(bins of 0.5 s over 0 .. 3.900 s\)"):
        m.draw_start(np.random.default_rng(0), "other", 0.1, weights, 0.5)
    with pytest.raises(ValueError, match="positive, finite width"):
        m.draw_start(np.random.default_rng(0), "other", 0.1, np.ones(8), 0.0)
