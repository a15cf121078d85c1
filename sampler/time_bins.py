"""Failure-weighted start times inside each clip (BeyondMimic, Liao et al. 2025, Sec. III-F;
mjlab's `MotionCommand._adaptive_sampling`): start episodes shortly before where the policy
recently failed.

Adaptive clip sampling (`clip_outcomes.py`) picks which clip; a long clip can be easy for four
seconds and fail at one jump, and uniform starts spend most episodes on the easy part. So each
clip's time is cut into bins of `bin_s` seconds (`--sampler.time-bin-s`, 0.25-0.5 s; mjlab uses
1 s bins on clips of minutes), and:

1. every failed training segment adds one count at the bin of the clip time it failed at
   (`ExecutorEnv.drain_segments`, sent by the actors, summed by the learner, reported here);
2. each tick that brings counts decays the old ones by `memory` (`--sampler.clip-memory`, the
   clip outcomes' EMA) and adds the new;
3. a look-back kernel spreads a failure at bin b over bins b, b-1 .. b-K with weights
   1, lambda .. lambda^K (`--sampler.time-kernel`, `--sampler.time-lambda`; mjlab's non-causal
   kernel covers b, b-1 and b-2 with lambda 0.8): starts land before the failure, where the
   policy can still recover, not after it;
4. the smoothed counts, normalized, take 1 - u of the start distribution and a uniform share u
   (`--sampler.time-uniform`, mjlab's 0.1) the rest, spread by time, so no stretch is forgotten;
5. a start is a bin drawn by those weights and a uniform time inside it, by the one
   `ClipManager.draw_start` every clip draw goes through.

Counts, not rates, as in BeyondMimic: a bin started more often also fails more often, and the
uniform share bounds that feedback. Starts stay `END_MARGIN_S` before a clip's end. A clip
without failures is drawn uniformly over its time, as before time bins.

Failure times arrive from outside (the learner's report): each is checked at entry (a clip this
sampler draws, a finite number, inside the clip) and a bad one is refused alone and counted
(`clips/time/refused`) with a one-line reason, never raised past `check`.
"""

from __future__ import annotations

import logging
import math
from typing import Any, Mapping, Sequence

import numpy as np

from common.motion.clip_manager import start_bins

log = logging.getLogger(__name__)

END_MARGIN_S = 0.1
"""Starts stay this far before a clip's end: the environment's own draws keep 3 control steps
(0.05 s at 60 Hz), and a clip's manifest length (`executor/clip_durations.py`) may run up to
0.2 ms past the loaded clip's, where a start would be refused."""
TIME_SLACK_S = 0.01
"""A failure time up to this far past the clip's (manifest) length still counts, in the last bin."""


class TimeBins:
    """Decayed failure counts per time bin of each clip, and the start weights they give."""

    def __init__(self, durations: Mapping[str, float], bin_s: float, kernel: int = 3, lam: float = 0.8,
                 uniform: float = 0.1, memory: float = 0.95):
        """`durations`: {clip id: length in s} of every clip drawn, in the clip manager's order."""
        if not (math.isfinite(bin_s) and bin_s > 0):
            raise ValueError(f"time bins of {bin_s!r} s; give a positive width")
        if not (isinstance(kernel, int) and 0 <= kernel) or not 0 <= lam <= 1 or not 0 < uniform <= 1:
            raise ValueError(f"time bin kernel {kernel!r}, lambda {lam!r}, uniform share {uniform!r}: "
                             "give an integer >= 0, a number in [0, 1] and one in (0, 1]")
        bad = [(c, d) for c, d in durations.items() if not (isinstance(d, (int, float)) and math.isfinite(d) and d >= 0)]
        if bad:
            raise ValueError(f"clip {bad[0][0]!r} lasts {bad[0][1]!r} s; a clip length is a finite number >= 0")
        self.clip_ids = tuple(durations)
        self.index = {c: i for i, c in enumerate(self.clip_ids)}
        self.durations = np.array([float(durations[c]) for c in self.clip_ids])
        self.bin_s, self.memory, self.uniform = float(bin_s), float(memory), float(uniform)
        self.kernel = np.power(float(lam), np.arange(kernel + 1))
        """Weight of a failure j bins later on a bin: lambda^j, j = 0..K."""
        self.bins = np.array([start_bins(d, self.bin_s) for d in self.durations], dtype=np.int64)
        """Per clip, the bins over its whole length [0, D] (where failures fall)."""
        self.start_bins = np.array([start_bins(max(0.0, d - END_MARGIN_S), self.bin_s) for d in self.durations],
                                   dtype=np.int64)
        """Per clip, the bins over its start range [0, D - END_MARGIN_S] (what `weights` covers)."""
        self.offsets = np.concatenate([[0], np.cumsum(self.bins)]).astype(np.int64)
        self.fails = np.zeros(int(self.offsets[-1]))
        """Decayed failure counts, every clip's bins one after another (clip i at offsets[i]:offsets[i+1])."""
        self._pending = np.zeros_like(self.fails)
        self.seen = 0
        """Failure times ever counted."""
        self.refused = 0
        """Failure times ever refused at entry."""
        self._weights: list[np.ndarray] = [self._weights_of(i) for i in range(len(self.clip_ids))]

    # ---- entry ----

    def check(self, clip_ids: Sequence[Any], times: Sequence[Any]) -> tuple[list[int], list[str]]:
        """(bin rows of the good entries, one reason per refused entry). A failure time is good
        when its clip is one this sampler draws and it is a finite number of seconds inside the
        clip (up to `TIME_SLACK_S` past its length). ValueError only when the two lists differ
        in length (the report is malformed as a whole)."""
        if len(clip_ids) != len(times):
            raise ValueError(f"failure times: {len(clip_ids)} clip ids and {len(times)} times; give one time per clip id")
        rows: list[int] = []
        refusals: list[str] = []
        for cid, t in zip(clip_ids, times):
            i = self.index.get(cid) if isinstance(cid, str) else None
            if i is None:
                refusals.append(f"failure time for clip {cid!r}: not a clip this sampler draws "
                                f"({len(self.clip_ids)} clips, e.g. {', '.join(self.clip_ids[:3])})")
                continue
            d = float(self.durations[i])
            if isinstance(t, bool) or not isinstance(t, (int, float, np.integer, np.floating)) or not math.isfinite(t) \
                    or not 0.0 <= float(t) <= d + TIME_SLACK_S:
                refusals.append(f"failure time {t!r} s in clip {cid!r}: allowed a finite number of seconds in "
                                f"[0, {d:.3f}] (the clip's length)")
                continue
            rows.append(int(self.offsets[i] + min(int(float(t) // self.bin_s), int(self.bins[i]) - 1)))
        return rows, refusals

    def add(self, rows: Sequence[int], refusals: Sequence[str] = ()) -> int:
        """Count what `check` accepted (held until the next `update`) and the refused entries
        (the first reason logged); returns the failures counted."""
        np.add.at(self._pending, np.asarray(rows, dtype=np.int64), 1.0)
        self.seen += len(rows)
        if refusals:
            self.refused += len(refusals)
            log.warning("sampler: %d failure time(s) refused; the first: %s", len(refusals), refusals[0])
        return len(rows)

    def update(self) -> None:
        """A tick: decay the counts by `memory`, add what was reported since the last tick, and
        recompute the start weights (nothing changes when nothing was reported)."""
        if not self._pending.any():
            return
        self.fails = self.memory * self.fails + self._pending
        self._pending[:] = 0.0
        self._weights = [self._weights_of(i) for i in range(len(self.clip_ids))]

    # ---- draws ----

    def _weights_of(self, i: int) -> np.ndarray:
        """Clip i's start weights over its `start_bins` (sum 1): see the module docstring, 3-4."""
        f = self.fails[self.offsets[i]:self.offsets[i + 1]]
        n = int(self.start_bins[i])
        padded = np.concatenate([f, np.zeros(len(self.kernel))])
        smoothed = sum(k * padded[j:j + n] for j, k in enumerate(self.kernel))
        hi = max(0.0, float(self.durations[i]) - END_MARGIN_S)
        edges = np.minimum(np.arange(n + 1) * self.bin_s, hi)
        width = np.diff(edges)
        uniform = width / width.sum() if width.sum() > 0 else np.full(n, 1.0 / n)
        total = float(smoothed.sum())
        if total <= 0:
            return uniform
        return (1.0 - self.uniform) * smoothed / total + self.uniform * uniform

    def weights(self, clip_id: str) -> np.ndarray:
        """The start-bin weights of `clip_id` (`ClipManager.draw_start`'s `bin_weights`, with
        `min_left_s=END_MARGIN_S` and `bin_s`)."""
        return self._weights[self.index[clip_id]]

    # ---- metrics and state ----

    def stats(self) -> dict[str, float]:
        """time/fails_seen, time/refused; time/entropy (mean over clips of more than one start
        bin of the start distribution's entropy over log(bins): 1 uniform, lower when starts
        gather before failures) and time/top_share (mean largest bin weight), as mjlab logs them."""
        multi = [w for w in self._weights if len(w) > 1]
        out = {"clips/time/fails_seen": float(self.seen), "clips/time/refused": float(self.refused)}
        if multi:
            ent = [float(-(w[w > 0] * np.log(w[w > 0])).sum() / math.log(len(w))) for w in multi]
            out["clips/time/entropy"] = float(np.mean(ent))
            out["clips/time/top_share"] = float(np.mean([w.max() for w in multi]))
        return out

    def state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """(meta, arrays) for the sampler's state: the bin width, each clip's id and bin count,
        and the counts as one array (those since the last tick apart: the next tick decays only
        the others)."""
        return ({"bin_s": self.bin_s, "clip_ids": list(self.clip_ids), "bins": [int(n) for n in self.bins],
                 "seen": self.seen, "refused": self.refused},
                {"clips/time_fails": self.fails.copy(), "clips/time_fails_pending": self._pending.copy()})

    def load_state(self, meta: dict[str, Any] | None, arrays: Mapping[str, np.ndarray]) -> int:
        """Restore `state()`; returns how many clips kept their counts. A clip keeps them when
        the saved run binned it the same (same id, bin width and bin count): a run resumed with
        another clip set or bin width starts the others without failures. No `meta` (a state
        from before time bins, or from a run without them): every clip starts without failures.
        ValueError naming the first malformed part; nothing is changed then."""
        if not meta:
            self._reset()
            return 0
        if not isinstance(meta, dict):
            raise ValueError(f"time bin state meta is a {type(meta).__name__}; expected a dict from TimeBins.state()")
        bin_s, ids, bins = meta.get("bin_s"), meta.get("clip_ids"), meta.get("bins")
        if isinstance(bin_s, bool) or not isinstance(bin_s, (int, float)) or not (math.isfinite(bin_s) and bin_s > 0):
            raise ValueError(f"time bin state bin_s = {bin_s!r}; expected a positive number of seconds")
        if not isinstance(ids, list) or not all(isinstance(c, str) for c in ids):
            raise ValueError("time bin state clip_ids: expected a list of clip ids")
        if not isinstance(bins, list) or len(bins) != len(ids) or not all(
                isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in bins):
            raise ValueError(f"time bin state bins: expected one whole number >= 1 per clip ({len(ids)} clips)")
        if "clips/time_fails" not in arrays:
            raise ValueError("time bin state lacks the array clips/time_fails")
        counts = np.asarray(arrays["clips/time_fails"], dtype=np.float64).reshape(-1)
        pending = np.asarray(arrays.get("clips/time_fails_pending", np.zeros(len(counts))), dtype=np.float64).reshape(-1)
        for name, a in (("counts", counts), ("pending counts", pending)):
            if len(a) != sum(bins) or not (np.isfinite(a).all() and (a >= 0).all()):
                raise ValueError(f"time bin state {name}: {len(a)} values for {sum(bins)} bins; expected one per bin, "
                                 "finite and >= 0")
        seen, refused = meta.get("seen", 0), meta.get("refused", 0)
        if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in (seen, refused)):
            raise ValueError(f"time bin state seen = {seen!r}, refused = {refused!r}; expected whole numbers >= 0")
        self._reset()
        kept = 0
        if float(bin_s) == self.bin_s:
            at = 0
            for cid, n in zip(ids, bins):
                i = self.index.get(cid)
                if i is not None and int(self.bins[i]) == n:
                    self.fails[self.offsets[i]:self.offsets[i + 1]] = counts[at:at + n]
                    self._pending[self.offsets[i]:self.offsets[i + 1]] = pending[at:at + n]
                    kept += 1
                at += n
        self.seen, self.refused = seen, refused
        self._weights = [self._weights_of(i) for i in range(len(self.clip_ids))]
        return kept

    def _reset(self) -> None:
        self.fails[:] = 0.0
        self._pending[:] = 0.0
        self.seen = self.refused = 0
        self._weights = [self._weights_of(i) for i in range(len(self.clip_ids))]
