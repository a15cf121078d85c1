"""`ClipManager`: which clip, and from which time, an environment plays (UniCon 2020, Sec. 5.1;
METHOD.md B "Training" and "Schedulers").

Every clip draw goes through one of these: the sampler's batch draws for new episodes
(`sampler/shape_sampler.py`, reweighted by adaptive clip sampling, `sampler/clip_outcomes.py`,
and with start times from failure-weighted time bins, `sampler/time_bins.py`), the dataset
scheduler's reschedules at a clip's end (`common/tasks/executor/schedulers/base.py`, built by
`ExecutorEnv` and `schedulers/factory.py` for play and the studio). A training episode's first
clip is the sampler's (sampler -> `actors/draws.py` -> `env.reset(..., clip_id, start_s)`), and
so is its start time when the sampler's time bins are on; every later clip (a reschedule) comes
from the environment's own manager, which holds the balancer's probabilities without the
sampler's adaptive weights (they do not travel with draws) and draws uniform starts.

    clips = ClipManager(pairs, duration_s=lambda c: motions[c].duration_s)  # pairs: (id, label)
    clip_id, start_s = clips.draw(rng)     # a balanced clip and a uniform start in it
    clips.draw_clips(rng, n)               # n clip ids at once (the sampler's draw)
    clips.reweight(factors)                # clip c drawn in proportion to p_c * factors[c]
    clips.draw_start(rng, c, 0.1, w, 0.5)  # a start in a 0.5 s bin drawn by the weights w

The clip probabilities are the motion balancer's (`balancer.MotionBalancer`: the class tree of
the labels, UniCon Eq. 8), or given outright (`ClipManager.with_probabilities`, e.g. a uniform
choice among clips named on the command line).
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

from common.motion.balancer import MotionBalancer

DurationFn = Callable[[str], float]
"""A clip's length in seconds, by clip id."""


def start_bins(span_s: float, bin_s: float) -> int:
    """How many bins of `bin_s` seconds cover the start range [0, span_s] (at least one; the
    last may be shorter): the length of `ClipManager.draw_start`'s `bin_weights`."""
    if not (math.isfinite(bin_s) and bin_s > 0):
        raise ValueError(f"time bins of {bin_s!r} s; give a positive, finite width")
    return max(1, math.ceil(max(0.0, span_s) / bin_s - 1e-9))


class ClipManager:
    """Clip draws from a `MotionBalancer` (optionally reweighted) and uniform start times."""

    def __init__(self, clips: Sequence[tuple[str, str]], weights: np.ndarray | None = None,
                 duration_s: DurationFn | None = None):
        """`clips`: (clip_id, label path) pairs of the motion library; `weights`: per-clip factors
        in the same order (see `reweight`; None: the balancer's own probabilities); `duration_s`:
        the length of a clip, needed for start times (`draw`, `draw_start`)."""
        self._setup(MotionBalancer(clips), duration_s)
        if weights is not None:
            self.reweight(weights)

    @classmethod
    def with_probabilities(cls, clip_ids: Sequence[str], probabilities: np.ndarray,
                           duration_s: DurationFn | None = None) -> "ClipManager":
        """A manager drawing `clip_ids` with these probabilities (used as given, in order; a
        repeated id is drawn through each of its entries) instead of the class tree's."""
        if not len(clip_ids):
            raise ValueError("a clip manager needs at least one clip")
        probs = np.asarray(probabilities, dtype=np.float64).reshape(-1)
        if probs.shape != (len(clip_ids),):
            raise ValueError(f"{len(probs)} probabilities for {len(clip_ids)} clips; give one per clip")
        manager = cls.__new__(cls)
        manager._setup(MotionBalancer.with_probabilities(clip_ids, probs), duration_s)
        return manager

    def _setup(self, balancer: MotionBalancer, duration_s: DurationFn | None) -> None:
        self.balancer = balancer
        """The clip distribution: `probabilities` (the class tree's or given), `draw_probabilities`
        (those times the `reweight` factors)."""
        self.clip_ids: tuple[str, ...] = balancer.clip_ids
        self.duration_s = duration_s

    @property
    def probabilities(self) -> np.ndarray:
        """`[n_clips]` base probabilities, in `clip_ids` order."""
        return self.balancer.probabilities

    @property
    def draw_probabilities(self) -> np.ndarray:
        """`[n_clips]` what the draws sample: `probabilities` times the `reweight` factors, renormalized."""
        return self.balancer.draw_probabilities

    def reweight(self, factors: np.ndarray) -> None:
        """Draw clip c in proportion to `probabilities[c] * factors[c]` (`clip_ids` order; positive
        and finite): the sampler's exp(-k r_c) of adaptive clip sampling."""
        self.balancer.set_factors(factors)

    def draw_clips(self, rng: np.random.Generator, n: int) -> list[str]:
        """`n` clip ids drawn independently (one vectorized `rng.choice`)."""
        return self.balancer.draw(rng, n)

    def draw_clip(self, rng: np.random.Generator) -> str:
        """One clip id (one `rng.choice`)."""
        return self.clip_ids[int(rng.choice(len(self.clip_ids), p=self.balancer.draw_probabilities))]

    def draw_start(self, rng: np.random.Generator, clip_id: str, min_left_s: float = 0.0,
                   bin_weights: np.ndarray | None = None, bin_s: float = 0.0) -> float:
        """A start time (s) in `clip_id` with at least `min_left_s` after it (from 0 when the clip
        is shorter than that); any clip `duration_s` knows, drawn or not.

        Uniform over that range [0, D - min_left_s] (one `rng.uniform`); or, given `bin_weights`
        (non-negative, not all zero, one per bin of `bin_s` seconds from the clip's start:
        `start_bins(D - min_left_s, bin_s)` of them), a bin drawn in proportion to its weight and a
        uniform time inside it, the last bin ending at the range's end (the sampler's
        failure-weighted starts, `sampler/time_bins.py`)."""
        if self.duration_s is None:
            raise ValueError("this clip manager was built without clip durations; it draws clip ids only")
        hi = max(0.0, self.duration_s(clip_id) - min_left_s)
        if bin_weights is None:
            return float(rng.uniform(0.0, hi))
        w = np.asarray(bin_weights, dtype=np.float64).reshape(-1)
        n = start_bins(hi, bin_s)
        if w.shape != (n,) or not (np.isfinite(w).all() and (w >= 0).all() and w.sum() > 0):
            raise ValueError(f"start bin weights of shape {w.shape} for clip {clip_id!r}; expected {n} weights "
                             f"(bins of {bin_s:g} s over 0 .. {hi:.3f} s), finite, >= 0 and not all zero")
        b = int(rng.choice(n, p=w / w.sum()))
        lo = b * bin_s
        return float(rng.uniform(lo, max(lo, min(hi, lo + bin_s))))

    def draw(self, rng: np.random.Generator, min_left_s: float = 0.0) -> tuple[str, float]:
        """(clip id, start time in s): `draw_clip`, then `draw_start` in it."""
        clip_id = self.draw_clip(rng)
        return clip_id, self.draw_start(rng, clip_id, min_left_s)

    def table(self) -> str:
        """The per-clip probabilities, one `clip_id  p` line per clip, most likely first."""
        return self.balancer.table()
