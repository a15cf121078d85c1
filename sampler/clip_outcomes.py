"""Adaptive clip sampling: draw the clips the policy fails on more often.

Won & Lee 2019 (Sec. 4.2, METHOD.md A) draw body shapes from exp(-k Vm / |Vbar|): shapes the
policy does badly on come up more. UniCon 2020's motion balancer (Sec. 5.1, Eq. 8; METHOD.md B)
draws clips by their place in the class tree only, whatever the policy can already do. This
joins the two: each clip's balancer probability p_c (Eq. 8) is multiplied by a factor of r_c,
the share of the clip's recent training segments tracked to the clip's end, and the class tree
still sets the base. Two factors (`--sampler.clip-weighting`):

- exp: exp(-k r_c). A clip the policy always tracks is drawn e^k times less often than one it
  never tracks; k = 0 is the balancer as UniCon has it (the default). Measured: k = 3 moved the
  draws too little to show in training.
- failure: max(floor, 1 - r_c), the recent failure share itself, as PHC (Luo et al. 2023) mines
  its failed sequences ("hard negative mining": sample in proportion to failure). A clip the
  policy never tracks weighs 1, one it always tracks `floor`. Since the factors are at most 1,
  every clip keeps at least floor x p_c after renormalizing, so every class of the tree keeps at
  least floor x its Eq. 8 share: none drops out of training once it is learnt (and forgotten).

A segment is the stretch of an episode on one clip: from the episode's start or a reschedule
to the clip's end (tracked), or to the termination that ended it (not tracked). The actors
count them, the learner sums them per iteration and sends them with its value report; each
tick decays the counts by `clip_memory` and adds the new ones, so r_c follows the policy.
r_c = (tracked + 1) / (segments + 2): Laplace's rule, 1/2 for a clip not yet seen.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np


WEIGHTINGS = ("exp", "failure")


class ClipOutcomes:
    """Decayed per-clip segment counts and the draw factors they give (exp(-k r_c) or
    max(floor, 1 - r_c))."""

    def __init__(self, clip_ids: Sequence[str], k: float, memory: float, weighting: str = "exp", floor: float = 0.1):
        if weighting not in WEIGHTINGS:
            raise ValueError(f"clip weighting {weighting!r} is not one of {', '.join(WEIGHTINGS)}")
        if not 0.0 < floor <= 1.0:
            raise ValueError(f"clip floor {floor!r} is not allowed: give a number in (0, 1]")
        self.clip_ids = tuple(clip_ids)
        self.index = {c: i for i, c in enumerate(self.clip_ids)}
        self.k, self.memory = float(k), float(memory)
        self.weighting, self.floor = weighting, float(floor)
        self.segments = np.zeros(len(self.clip_ids))
        self.tracked = np.zeros(len(self.clip_ids))
        self._pending_segments = np.zeros(len(self.clip_ids))
        self._pending_tracked = np.zeros(len(self.clip_ids))
        self.seen = 0  # segments ever reported

    def check(self, clip_ids: Sequence[str], segments: Sequence[int], tracked: Sequence[int]) -> list[tuple[int, int, int]]:
        """(row, segments, tracked) per entry, or ValueError naming the first clip this sampler
        does not draw or counts that do not add up."""
        if not len(clip_ids) == len(segments) == len(tracked):
            raise ValueError(f"clip outcomes of {len(clip_ids)} clips, {len(segments)} segment counts and "
                             f"{len(tracked)} tracked counts; give one of each per clip")
        rows = []
        for cid, n, t in zip(clip_ids, segments, tracked):
            if cid not in self.index:
                raise ValueError(f"clip outcome for {cid!r}: not a clip this sampler draws "
                                 f"({len(self.clip_ids)} clips, e.g. {', '.join(self.clip_ids[:3])})")
            if not 0 <= int(t) <= int(n):
                raise ValueError(f"clip outcome for {cid!r}: {t} tracked of {n} segments; allowed: 0 <= tracked <= segments")
            rows.append((self.index[cid], int(n), int(t)))
        return rows

    def report(self, clip_ids: Sequence[str], segments: Sequence[int], tracked: Sequence[int]) -> int:
        """Add one report's counts (held until the next `update`); returns the segments added.
        ValueError (`check`) before anything is stored."""
        return self.add(self.check(clip_ids, segments, tracked))

    def add(self, rows: list[tuple[int, int, int]]) -> int:
        """Add counts `check` accepted; returns the segments added."""
        for i, n, t in rows:
            self._pending_segments[i] += n
            self._pending_tracked[i] += t
        added = sum(n for _, n, _ in rows)
        self.seen += added
        return added

    def update(self) -> None:
        """A tick: decay the counts by `memory`, add what was reported since the last tick."""
        if not self._pending_segments.any():
            return
        self.segments = self.memory * self.segments + self._pending_segments
        self.tracked = self.memory * self.tracked + self._pending_tracked
        self._pending_segments[:] = 0.0
        self._pending_tracked[:] = 0.0

    @property
    def tracked_rate(self) -> np.ndarray:
        """r_c per clip, in `clip_ids` order: (tracked + 1) / (segments + 2)."""
        return (self.tracked + 1.0) / (self.segments + 2.0)

    @property
    def active(self) -> bool:
        """Whether the factors reweight the draws (false for exp with k = 0: all ones)."""
        return self.weighting == "failure" or self.k > 0

    def factors(self) -> np.ndarray:
        """Per clip, in `clip_ids` order: exp(-k r_c) (all ones for k = 0), or max(floor, 1 - r_c)."""
        if self.weighting == "failure":
            return np.maximum(self.floor, 1.0 - self.tracked_rate)
        return np.exp(-self.k * self.tracked_rate)

    @property
    def success(self) -> np.ndarray:
        """Per clip, the decayed share of segments tracked to the clip's end (NaN for a clip
        never seen): what the metrics show, without Laplace's prior."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.segments > 0, self.tracked / np.where(self.segments > 0, self.segments, 1.0), np.nan)

    def stats(self) -> dict[str, float]:
        """segments_seen, rate_min/max (r_c) and, once segments were counted, tracked_pct."""
        rate = self.tracked_rate
        total = self.segments.sum()
        out = {"clips/segments_seen": float(self.seen), "clips/rate_min": float(rate.min()), "clips/rate_max": float(rate.max())}
        if total > 0:
            out["clips/tracked_pct"] = float(100.0 * self.tracked.sum() / total)
        return out

    def state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """(meta, arrays) for the sampler's state; counts keyed by clip id in `meta`."""
        return ({"clip_ids": list(self.clip_ids), "seen": self.seen},
                {"clips/segments": self.segments + self._pending_segments, "clips/tracked": self.tracked + self._pending_tracked})

    def load_state(self, meta: dict[str, Any] | None, arrays: dict[str, np.ndarray]) -> None:
        """Restore `state()`. Counts of clips this sampler no longer draws are dropped and new
        clips start unseen (a run resumed with another clip set); a state from before adaptive
        clip sampling (no `meta`) starts every clip unseen."""
        self.segments[:] = 0.0
        self.tracked[:] = 0.0
        self._pending_segments[:] = 0.0
        self._pending_tracked[:] = 0.0
        if not meta:
            self.seen = 0
            return
        ids = [str(c) for c in meta["clip_ids"]]
        segments = np.asarray(arrays["clips/segments"], dtype=np.float64).reshape(-1)
        tracked = np.asarray(arrays["clips/tracked"], dtype=np.float64).reshape(-1)
        if not len(ids) == len(segments) == len(tracked):
            raise ValueError(f"clip outcome state of {len(ids)} clips with {len(segments)} and {len(tracked)} counts")
        if not (np.isfinite(segments).all() and np.isfinite(tracked).all() and (0 <= tracked).all()
                and (tracked <= segments + 1e-9).all()):
            raise ValueError("clip outcome state: counts must be finite with 0 <= tracked <= segments")
        for cid, n, t in zip(ids, segments, tracked):
            if cid in self.index:
                self.segments[self.index[cid]], self.tracked[self.index[cid]] = n, t
        self.seen = int(meta.get("seen", 0))
