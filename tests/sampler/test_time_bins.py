"""Failure-weighted start times (sampler/time_bins.py): where a clip failed, starts gather just
before; bad failure times are refused one by one; the counts live in the sampler's state."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from common.params import ParamSpace
from sampler.config import SamplerConfig
from sampler.shape_sampler import ShapeSampler
from sampler.time_bins import END_MARGIN_S, TimeBins

CLIPS = [("long", "root/a/x"), ("short", "root/a/y"), ("other", "root/b")]
DURATIONS = {"long": 4.0, "short": 0.3, "other": 2.0}
SPACE = ParamSpace(names=("x",), low=(0.0,), high=(1.0,))
CFG = SamplerConfig(n_mcmc=16, n_chains=4, burn_in=4, vm_fit_steps=2, probe_points=16, clip_memory=0.5,
                    time_bin_s=0.5, time_kernel=3, time_lambda=0.8, time_uniform=0.1, seed=4)


def test_starts_gather_before_a_failure_more_than_uniform_starts_would():
    """Failures at 3.1 s of a 4 s clip (bin 6 of 0.5 s): the look-back kernel puts 90% of the
    starts in bins 3..6 ([1.5, 3.5) s, weights 0.8^3 .. 1) and the 10% uniform share spreads the
    rest. The 1.6 s before the failure hold 41% of the start range [0, 3.9], so uniform starts put
    41% there; these put 70% (0.9 x 2.15 / 2.95 + 0.1 x 0.41)."""
    s = ShapeSampler(CFG, SPACE, CLIPS, DURATIONS)
    before = np.array(s.draw_starts(["long"] * 4000))
    assert ((1.5 <= before) & (before < 3.1)).mean() == pytest.approx(1.6 / 3.9, abs=0.03)  # no failures: uniform
    assert before.max() <= 4.0 - END_MARGIN_S
    assert s.report(np.full((1, 1), 0.5), np.ones(1), failures=(["long"] * 50, [3.1] * 50)) == 1
    s.tick(1)
    starts = np.array(s.draw_starts(["long"] * 4000))
    window = ((1.5 <= starts) & (starts < 3.1)).mean()
    assert window > 1.5 * 1.6 / 3.9, window
    assert window == pytest.approx(0.9 * (0.8**3 + 0.8**2 + 0.8 + 0.2) / (0.8**3 + 0.8**2 + 0.8 + 1) + 0.1 * 1.6 / 3.9,
                                   abs=0.03)
    assert ((1.5 <= starts) & (starts < 3.5)).mean() == pytest.approx(0.9 + 0.1 * 2.0 / 3.9, abs=0.02)
    assert (starts >= 3.5).mean() < 0.05  # hardly any start after the failure's bin
    assert starts.min() >= 0.0 and starts.max() <= 4.0 - END_MARGIN_S


def test_weights_are_the_kernel_over_the_failures_plus_the_uniform_share_and_decay_at_each_tick():
    tb = TimeBins(DURATIONS, 0.5, kernel=2, lam=0.5, uniform=0.2, memory=0.5)
    assert list(tb.bins) == [8, 1, 4] and list(tb.start_bins) == [8, 1, 4]
    np.testing.assert_allclose(tb.weights("long"), [0.5 / 3.9] * 7 + [0.4 / 3.9])  # uniform over time
    rows, refused = tb.check(["long", "long"], [2.2, 3.99])  # bins 4 and 7
    assert refused == [] and tb.add(rows) == 2
    np.testing.assert_allclose(tb.weights("long"), [0.5 / 3.9] * 7 + [0.4 / 3.9])  # held until the tick
    tb.update()
    smooth = np.array([0, 0, 0.25, 0.5, 1, 0.25, 0.5, 1])  # bin 4: 1, .5, .25 on 4, 3, 2; bin 7 on 7, 6, 5
    uniform = np.array([0.5] * 7 + [0.4]) / 3.9
    np.testing.assert_allclose(tb.weights("long"), 0.8 * smooth / smooth.sum() + 0.2 * uniform)
    tb.add(*tb.check(["other"], [0.1]))
    tb.update()  # the old counts halve
    np.testing.assert_allclose(tb.fails[tb.offsets[0]:tb.offsets[1]], [0, 0, 0, 0, 0.5, 0, 0, 0.5])
    np.testing.assert_allclose(tb.fails[tb.offsets[2]:tb.offsets[3]], [1, 0, 0, 0])
    np.testing.assert_allclose(tb.weights("short"), [1.0])  # one bin: nowhere else to start
    stats = tb.stats()
    assert stats["clips/time/fails_seen"] == 3 and stats["clips/time/refused"] == 0
    assert 0 < stats["clips/time/entropy"] < 1 and stats["clips/time/top_share"] > 1 / 4


@pytest.mark.parametrize("clip, time, allowed", [
    ("nope", 1.0, "'nope': not a clip this sampler draws"),
    ("long", -0.5, r"-0.5 s in clip 'long': allowed a finite number of seconds in \[0, 4.000\]"),
    ("long", 4.5, r"4.5 s in clip 'long': allowed"),
    ("long", math.nan, "nan s in clip 'long'"),
    ("long", math.inf, "inf s in clip 'long'"),
    ("long", True, "True s in clip 'long'"),
    ("long", "1.0", "'1.0' s in clip 'long'"),
    (7, 1.0, "clip 7: not a clip"),
])
def test_a_bad_failure_time_is_refused_alone_counted_and_named(clip, time, allowed):
    s = ShapeSampler(CFG, SPACE, CLIPS, DURATIONS)
    assert s.report(np.full((2, 1), 0.5), np.ones(2), failures=([clip, "other"], [time, 1.2])) == 2  # the pairs are stored
    assert len(s.refused_last) == 1
    assert re.search(allowed, s.refused_last[0]), s.refused_last
    s.tick(1)
    stats = s.stats()
    assert stats["clips/time/refused"] == 1 and stats["clips/time/fails_seen"] == 1  # the good one counted
    assert s.report_failures(["long"], [4.005]) == 1  # within the slack: the last bin
    with pytest.raises(ValueError, match="give one time per clip id"):
        s.report_failures(["long", "long"], [1.0])


def test_time_bins_need_clip_lengths_and_a_sampler_without_them_takes_no_failure_times():
    with pytest.raises(ValueError, match=r"needs every clip's length; none for \['other'\]"):
        ShapeSampler(CFG, SPACE, CLIPS, {"long": 4.0, "short": 0.3})
    off = ShapeSampler(dataclasses.replace(CFG, time_bin_s=0.0), SPACE, CLIPS, DURATIONS)
    assert off.time_bins is None and off.draw_starts(["long"]) == []
    p, clips, starts = off.draw_episodes(5)
    assert len(clips) == 5 and starts == []
    with pytest.raises(ValueError, match="keeps no time bins"):
        off.report_failures(["long"], [1.0])
    with pytest.raises(ValueError, match="a clip length is a finite number >= 0"):
        TimeBins({"long": -1.0}, 0.5)


def test_state_round_trips_keeps_the_clips_that_match_and_refuses_a_malformed_one():
    a = ShapeSampler(CFG, SPACE, CLIPS, DURATIONS)
    a.report_failures(["long"] * 20 + ["other"] * 5, [3.1] * 20 + [0.2] * 5)
    a.tick(1)
    a.report_failures(["long"], [0.3])  # pending at the save: the next tick decays only the others
    state = a.state_dict()
    b = ShapeSampler(dataclasses.replace(CFG, seed=9), SPACE, CLIPS, DURATIONS)
    b.load_state_dict(state)
    np.testing.assert_array_equal(b.time_bins.fails, a.time_bins.fails)
    for c in DURATIONS:
        np.testing.assert_array_equal(b.time_bins.weights(c), a.time_bins.weights(c))
    a.tick(2)
    b.tick(2)
    np.testing.assert_array_equal(b.time_bins.fails, a.time_bins.fails)
    assert a.draw_starts(["long"] * 10) == b.draw_starts(["long"] * 10)  # the same generator state too
    # resumed with another clip set: "long" kept, "other" now lasts 3 s (6 bins, not 4) and starts
    # without failures, "new" too; a clip the saved run drew and this one does not is dropped
    c = ShapeSampler(CFG, SPACE, [("long", "root/a/x"), ("other", "root/b"), ("new", "root/c")],
                     {"long": 4.0, "other": 3.0, "new": 1.0})
    c.load_state_dict(state)
    np.testing.assert_array_equal(c.time_bins.fails[:8], state["arrays"]["clips/time_fails"][:8])
    assert not c.time_bins.fails[c.time_bins.offsets[1]:].any()
    # another bin width: nothing kept; a state from a run without time bins: nothing either
    d = ShapeSampler(dataclasses.replace(CFG, time_bin_s=0.25), SPACE, CLIPS, DURATIONS)
    d.load_state_dict(state)
    assert not d.time_bins.fails.any()
    plain = ShapeSampler(dataclasses.replace(CFG, time_bin_s=0.0), SPACE, CLIPS, DURATIONS)
    d.load_state_dict(plain.state_dict())
    assert not d.time_bins.fails.any() and d.time_bins.seen == 0
    for edit, message in [
        (lambda m, a: a.__setitem__("clips/time_fails", a["clips/time_fails"][:-1]), "12 values for 13 bins"),
        (lambda m, a: a.__setitem__("clips/time_fails", -a["clips/time_fails"]), "finite and >= 0"),
        (lambda m, a: a.pop("clips/time_fails"), "lacks the array clips/time_fails"),
        (lambda m, a: m["time_bins"].__setitem__("bin_s", -1), "bin_s = -1"),
        (lambda m, a: m["time_bins"].__setitem__("bins", [8, 1]), "one whole number >= 1 per clip"),
        (lambda m, a: m["time_bins"].__setitem__("clip_ids", "long"), "a list of clip ids"),
    ]:
        bad = {"meta": {**state["meta"], "time_bins": dict(state["meta"]["time_bins"])},
               "arrays": dict(state["arrays"])}
        edit(bad["meta"], bad["arrays"])
        fresh = ShapeSampler(CFG, SPACE, CLIPS, DURATIONS)
        with pytest.raises(ValueError, match=message):
            fresh.load_state_dict(bad)
