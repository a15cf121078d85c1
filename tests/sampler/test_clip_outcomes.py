"""Adaptive clip sampling (sampler/clip_outcomes.py): the balancer's probabilities reweighted by
exp(-k r_c), r_c the share of a clip's recent training segments tracked to its end."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from common.motion.balancer import MotionBalancer
from sampler.clip_outcomes import ClipOutcomes
from sampler.config import SamplerConfig
from sampler.shape_sampler import ShapeSampler
from common.params import ParamSpace

CLIPS = [("easy", "root/a"), ("hard", "root/b/x"), ("other", "root/b/y")]


def test_rates_follow_the_counts_with_laplaces_rule_and_decay():
    o = ClipOutcomes(["easy", "hard", "other"], k=2.0, memory=0.5)
    np.testing.assert_allclose(o.tracked_rate, 0.5)  # nothing seen: 1/2 each
    np.testing.assert_allclose(o.factors(), math.exp(-1.0))
    assert o.report(["easy", "hard"], [8, 8], [8, 0]) == 16
    np.testing.assert_allclose(o.tracked_rate, 0.5)  # held until the tick
    o.update()
    np.testing.assert_allclose(o.tracked_rate, [9 / 10, 1 / 10, 1 / 2])
    np.testing.assert_allclose(o.factors(), np.exp(-2.0 * np.array([0.9, 0.1, 0.5])))
    o.report(["easy"], [4], [0])
    o.update()  # the old counts weigh half: easy (4 + 0) / (4 + 4) tracked
    np.testing.assert_allclose(o.segments[0], 8.0)
    np.testing.assert_allclose(o.tracked_rate[0], 5 / 10)
    assert o.stats()["clips/segments_seen"] == 20
    assert o.stats()["clips/tracked_pct"] == pytest.approx(100 * 4 / (8 + 4))  # easy 4 of 8, hard 0 of 4


@pytest.mark.parametrize("ids, segments, tracked, message", [
    (["easy", "nope"], [1, 1], [1, 1], "'nope': not a clip this sampler draws"),
    (["easy"], [2], [3], "3 tracked of 2 segments"),
    (["easy"], [2], [-1], "-1 tracked of 2 segments"),
    (["easy", "hard"], [2], [1, 1], "give one of each per clip"),
])
def test_a_bad_report_is_refused_whole(ids, segments, tracked, message):
    o = ClipOutcomes(["easy", "hard"], k=1.0, memory=0.9)
    with pytest.raises(ValueError, match=message):
        o.report(ids, segments, tracked)
    o.update()
    assert o.seen == 0 and not o.segments.any()


def test_draws_follow_the_balancer_times_the_factors():
    b = MotionBalancer(CLIPS)
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    before = b.draw(rng_a, 50)
    b.set_factors(np.ones(3))  # factors of one: the balancer's own draws
    assert b.draw(rng_b, 50) == before
    b.set_factors(np.array([0.1, 1.0, 1.0]))
    expected = np.array([0.5 * 0.1, 0.25, 0.25]) / 0.55
    np.testing.assert_allclose(b.draw_probabilities, expected)
    np.testing.assert_allclose(b.probabilities, [0.5, 0.25, 0.25])  # the tree's own stay
    draws = b.draw(np.random.default_rng(0), 20000)
    freq = np.array([draws.count(c) for c in ("easy", "hard", "other")]) / 20000
    np.testing.assert_allclose(freq, expected, atol=0.015)
    for bad in (np.array([1.0, 0.0, 1.0]), np.array([1.0, np.nan, 1.0]), np.ones(2)):
        with pytest.raises(ValueError, match="positive and finite"):
            b.set_factors(bad)


SPACE = ParamSpace(names=("x",), low=(0.0,), high=(1.0,))
FAST = SamplerConfig(n_mcmc=16, n_chains=4, burn_in=4, vm_fit_steps=2, probe_points=16, clip_k=3.0, clip_memory=0.9)


def test_the_sampler_draws_a_clip_it_fails_on_more_after_a_tick_and_keeps_that_through_its_state():
    s = ShapeSampler(FAST, SPACE, CLIPS)
    s.report_clips(["easy", "hard"], [50, 50], [50, 0])
    np.testing.assert_allclose(s.balancer.draw_probabilities, [0.5, 0.25, 0.25])  # not before the tick
    stats = s.tick(1)
    p = s.balancer.draw_probabilities
    assert p[1] > p[2] > p[0]  # hard (rate ~0) over other (unseen, 1/2) over easy (~1)
    assert stats["clips/tracked_pct"] == pytest.approx(50.0) and stats["clips/segments_seen"] == 100
    assert stats["clips/p_max"] == pytest.approx(p.max())
    restored = ShapeSampler(dataclasses.replace(FAST, seed=9), SPACE, [*CLIPS, ("new", "root/c")])
    restored.load_state_dict(s.state_dict())
    np.testing.assert_allclose(restored.clip_outcomes.segments[:3], s.clip_outcomes.segments)
    assert restored.clip_outcomes.segments[3] == 0  # a clip the saved run did not draw starts unseen
    q = restored.balancer.draw_probabilities
    assert q[1] > q[2] > q[0]
    with pytest.raises(ValueError, match="'nope'"):
        s.report_clips(["nope"], [1], [0])
    off = ShapeSampler(dataclasses.replace(FAST, clip_k=0.0), SPACE, CLIPS)
    off.report_clips(["easy", "hard"], [50, 50], [50, 0])
    off.tick(1)
    np.testing.assert_allclose(off.balancer.draw_probabilities, [0.5, 0.25, 0.25])  # k = 0: UniCon's balancer
    assert off.stats()["clips/tracked_pct"] == pytest.approx(50.0)  # still measured


def test_a_sampler_without_clips_refuses_clip_outcomes():
    s = ShapeSampler(FAST, SPACE)
    assert s.report_clips([], [], []) == 0
    with pytest.raises(ValueError, match="draws no clips"):
        s.report_clips(["easy"], [1], [1])


def test_failure_weighting_moves_draws_to_failing_clips_and_the_floor_keeps_every_class():
    """`--sampler.clip-weighting failure`: factor max(floor, 1 - r_c). The clip never tracked
    takes the most draws; the clips always tracked keep at least floor x their class-tree share,
    so class a, learnt whole, stays in play."""
    o = ClipOutcomes(["easy", "hard", "other"], k=0.0, memory=0.9, weighting="failure", floor=0.1)
    assert o.active  # k does not matter here
    np.testing.assert_allclose(o.factors(), 0.5)  # unseen: Laplace's 1/2
    o.report(["easy", "hard", "other"], [200, 200, 200], [200, 0, 100])
    o.update()
    np.testing.assert_allclose(o.factors(), [0.1, 1 - 1 / 202, 1 - 101 / 202])  # easy at the floor
    s = ShapeSampler(dataclasses.replace(FAST, clip_weighting="failure", clip_floor=0.1, clip_k=0.0), SPACE, CLIPS)
    base = s.balancer.probabilities.copy()
    s.report_clips(["easy", "hard", "other"], [200, 200, 200], [200, 0, 100])
    s.tick(1)
    p = s.balancer.draw_probabilities
    assert p[1] > p[2] > p[0] and p[1] > base[1]  # hard gains, easy loses
    assert (p >= 0.1 * base - 1e-12).all()  # the floor: every clip keeps a tenth of its share
    _, clips = s.draw(20000)
    freq = np.array([clips.count(c) for c in ("easy", "hard", "other")]) / 20000
    np.testing.assert_allclose(freq, p, atol=0.015)
    assert freq[0] > 0.02  # class a (easy alone) still drawn
    stats = s.stats()
    assert stats["clips/class/root/a/success_pct"] == pytest.approx(100.0)
    assert stats["clips/class/root/b/x/success_pct"] == pytest.approx(0.0)
    assert stats["clips/clip/hard/starts_pct"] == pytest.approx(100 * freq[1], abs=1e-9)
    # every clip always tracked: all at the floor, back to the class tree's own shares
    s.report_clips(["easy", "hard", "other"], [10**6] * 3, [10**6] * 3)
    s.tick(2)
    np.testing.assert_allclose(s.balancer.draw_probabilities, base, atol=1e-6)


@pytest.mark.parametrize("kw, message", [(dict(weighting="worst"), "not one of exp, failure"),
                                         (dict(weighting="failure", floor=0.0), r"give a number in \(0, 1\]")])
def test_bad_weighting_options_are_refused(kw, message):
    with pytest.raises(ValueError, match=message):
        ClipOutcomes(["easy"], k=0.0, memory=0.9, **kw)


def test_config_refuses_a_bad_weighting_floor_or_bin():
    for bad, message in [(dict(clip_weighting="worst"), "give exp or failure"), (dict(clip_floor=0.0), "clip-floor"),
                         (dict(time_bin_s=0.01), "give 0 \\(off\\) or a bin"), (dict(time_uniform=0.0), "time-uniform")]:
        with pytest.raises(ValueError, match=message):
            dataclasses.replace(SamplerConfig(), **bad)
