"""What the sampler's clip draws did, per class and per clip, for TensorBoard: the share of
episode starts each got and how often its training segments were tracked to the clip's end.

Adaptive clip sampling (`clip_outcomes.py`) moves starts toward failing clips; these metrics
show whether it does and whether the failing ones improve. Classes are the clips' labels cut
to `CLASS_DEPTH` levels below the root (`root/locomotion/walk`, `root/bandai/bow`): the level of
UniCon's class tree whose share Eq. 8 fixes, and few enough to read as scalars (10 for the core
clips, about 30 with the Bandai takes).

Per clip, scalars for every clip while there are at most `PER_CLIP_MAX` of them (the core 24
and their mirrors). Beyond that, hundreds of curves cannot be read: the clip-level spread
(`clips/success_pct/min`, `p25`, `median`) and, at each tick, the `WORST_CLIPS` clips of lowest
success by name, so the clips that hold training back show up as curves of their own (a point
at each tick they are among the worst). Histograms would need a second channel from the
sampler to the logger and do not name a clip.

Starts are the draws the sampler served (an actor may leave the end of its last batch unused),
decayed at each tick like the outcome counts and kept in the sampler's state; success is the
decayed share of segments tracked (`ClipOutcomes`). A clip or class without counted segments
has no success key yet.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from common.wire import MAX_KEY

CLASS_DEPTH = 2
"""Label levels below the root that make a class: `root/locomotion/walk`."""
PER_CLIP_MAX = 64
"""Most clips that get per-clip scalars every tick."""
WORST_CLIPS = 8
"""Clips of lowest success named at each tick when there are more than `PER_CLIP_MAX`."""


def clip_class(label: str, depth: int = CLASS_DEPTH) -> str:
    """The class of a clip label: its first `depth` levels below the root (a shorter label is
    its own class)."""
    parts = [p for p in label.strip("/").split("/") if p]
    return "/".join(parts[: depth + 1])


class ClipMetrics:
    """Decayed start counts per clip, and the per-class and per-clip metrics."""

    def __init__(self, clips: Sequence[tuple[str, str]], memory: float):
        self.clip_ids = tuple(c for c, _ in clips)
        self.index = {c: i for i, c in enumerate(self.clip_ids)}
        classes = [clip_class(label) for _, label in clips]
        self.class_names = sorted(set(classes))
        self.class_of = np.array([self.class_names.index(c) for c in classes], dtype=np.int64)
        self.memory = float(memory)
        self.starts = np.zeros(len(self.clip_ids))
        self._pending = np.zeros(len(self.clip_ids))

    def count(self, clip_ids: Sequence[str]) -> None:
        """Count drawn starts (clip ids this sampler drew; held until the next `update`)."""
        np.add.at(self._pending, np.array([self.index[c] for c in clip_ids], dtype=np.int64), 1.0)

    def update(self) -> None:
        """A tick: decay the start counts by `memory` and add the new ones."""
        if self._pending.any():
            self.starts = self.memory * self.starts + self._pending
            self._pending[:] = 0.0

    def stats(self, segments: np.ndarray, tracked: np.ndarray) -> dict[str, float]:
        """`clips/class/<class>/{starts_pct,success_pct}`, per clip `clips/clip/<id>/{starts_pct,
        success_pct}` (all clips, or the worst few; see the module docstring) and the spread of
        per-clip success. `segments`, `tracked`: the decayed counts per clip (`ClipOutcomes`)."""
        starts = self.starts + self._pending
        total = starts.sum()
        share = 100.0 * starts / total if total > 0 else np.zeros_like(starts)
        out: dict[str, float] = {}
        n = len(self.class_names)
        cls_starts = np.bincount(self.class_of, share, minlength=n)
        cls_segments = np.bincount(self.class_of, segments, minlength=n)
        cls_tracked = np.bincount(self.class_of, tracked, minlength=n)
        for k, name in enumerate(self.class_names):
            out[f"clips/class/{name}/starts_pct"] = float(cls_starts[k])
            if cls_segments[k] > 0:
                out[f"clips/class/{name}/success_pct"] = _pct(cls_tracked[k], cls_segments[k])
        success = np.array([_pct(t, s) for t, s in zip(tracked, segments)])
        seen = np.flatnonzero(np.isfinite(success))
        if len(self.clip_ids) <= PER_CLIP_MAX:
            named = range(len(self.clip_ids))
        else:
            order = seen[np.lexsort((-segments[seen], success[seen]))]  # lowest success, then most segments
            named = order[:WORST_CLIPS]
        for i in named:
            cid = self.clip_ids[i]
            if len(f"clips/clip/{cid}/success_pct") + len("sampler/") <= MAX_KEY:
                out[f"clips/clip/{cid}/starts_pct"] = float(share[i])
                if np.isfinite(success[i]):
                    out[f"clips/clip/{cid}/success_pct"] = float(success[i])
        if len(seen):
            out["clips/success_pct/min"] = float(success[seen].min())
            out["clips/success_pct/p25"] = float(np.percentile(success[seen], 25))
            out["clips/success_pct/median"] = float(np.median(success[seen]))
        return out

    def state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """(meta, arrays) for the sampler's state: the start counts by clip id, and those since
        the last tick apart (the next tick decays only the first)."""
        return {"clip_ids": list(self.clip_ids)}, {"clips/starts": self.starts.copy(), "clips/starts_pending": self._pending.copy()}

    def load_state(self, meta: dict[str, Any] | None, arrays: Mapping[str, np.ndarray]) -> None:
        """Restore `state()`: counts of clips this sampler draws are kept, others dropped, new
        clips start at zero (no `meta`: a state from before these metrics, all zero).
        ValueError naming what is malformed; nothing is changed then."""
        if not meta:
            self.starts[:] = 0.0
            self._pending[:] = 0.0
            return
        ids = meta.get("clip_ids") if isinstance(meta, dict) else None
        if not isinstance(ids, list) or not all(isinstance(c, str) for c in ids) or "clips/starts" not in arrays:
            raise ValueError("clip metrics state: expected clip_ids (a list of clip ids) and the array clips/starts")
        counts = np.asarray(arrays["clips/starts"], dtype=np.float64).reshape(-1)
        pending = np.asarray(arrays.get("clips/starts_pending", np.zeros(len(ids))), dtype=np.float64).reshape(-1)
        if not len(counts) == len(pending) == len(ids) or not (np.isfinite(counts).all() and (counts >= 0).all()
                                                               and np.isfinite(pending).all() and (pending >= 0).all()):
            raise ValueError(f"clip metrics state: {len(counts)} start counts for {len(ids)} clips; "
                             "expected one per clip, finite and >= 0")
        self.starts[:] = 0.0
        self._pending[:] = 0.0
        for cid, n, p in zip(ids, counts, pending):
            if cid in self.index:
                self.starts[self.index[cid]], self._pending[self.index[cid]] = n, p


def _pct(tracked: float, segments: float) -> float:
    return float(100.0 * tracked / segments) if segments > 0 else float("nan")
