"""Motion stitching: clips played one after the other, joined by slerp transition frames (UniCon
2020, METHOD.md B "Schedulers": "motion stitching: a FIFO of target frames, slerp transition
frames between clips").

    s = StitchScheduler(model, motion_fn, dt_s, clips=("humanoid3d_walk", ("humanoid3d_run", 0.2, 0.7)))
    s.begin(rng, align_to=character_qpos)   # the queue's head, placed under the character
    s.enqueue("humanoid3d_kick")            # any time: played after what is queued

Frames are kept as one array of placed qpos rows on the control grid (the FIFO): `frame(i)` is
row k + i, `advance` moves k on and appends the next piece when the lookahead needs it. A
clip's rows are sampled at once (`CharacterMotion.qpos` on an array of times, vectorised
slerp); a stitch appends, in one vectorised blend (`PoseMath.blend`):

- the next clip turned about the vertical so its first frame has the heading of the previous
  piece's last frame (`place`, as the dataset scheduler aligns a reschedule);
- `transition_s` of transition frames slerping every joint, the root height and orientation
  from the previous last frame to the next first frame, while the root's horizontal position
  moves on with a velocity blended from the previous clip's end velocity to the next clip's
  start velocity (a stitch does not stop the character);
- the next clip shifted to start where that path ends.

So a stitch spreads the pose difference of the two clips over the transition: no per-step jump
is larger than that difference / (transition steps + 1) (a test checks it against the steps
within the clips). When the queue runs dry the last frame is held (`at_end="hold"`, targets at
rest), or the schedule is `done` (`at_end="stop"`), or, with `loop=True`, everything enqueued
so far is queued again. `begin` restarts that program from its top; an episode's reset does
not call it (`restarts_on_reset` is False: `ExecutorEnv.reset` puts the character on the
current frame and the queue plays on).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Iterable, Sequence, Union

import mujoco
import numpy as np

from common.tasks.observations import heading, quat_to_mat, yaw_matrix
from common.tasks.executor.schedulers.pose_blend import PoseMath
from common.tasks.executor.schedulers.base import MotionFn, TargetFrame, place


@dataclass(frozen=True)
class StitchItem:
    """One queued clip: `clip_id` from `start_s` (None: 0) to `end_s` (None: its end), seconds."""

    clip_id: str
    start_s: float | None = None
    end_s: float | None = None


ClipSpec = Union[str, StitchItem, Sequence]
"""A clip id, a `StitchItem`, or a tuple (clip_id, start_s, end_s) (start and end optional)."""


@dataclass
class _Segment:
    """A run of rows of the FIFO: `kind` clip | transition | hold, from absolute row `start`."""

    kind: str
    start: int
    clip_id: str
    t0: float = 0.0
    duration_s: float = 0.0
    rows: int = 0


class StitchScheduler:
    """A FIFO of clips joined by slerp transitions (UniCon 2020, METHOD.md B "Schedulers": motion
    stitching); see the module docstring.

    model: the character's model (the executor's `ref_model`); motion_fn: clip id ->
    `CharacterMotion` on it (the executor's `_motion`); dt_s: the control step; speed: playback
    speed; lookback/lookahead: rows kept before frame 0 (reactive initialization asks up to
    -lookback) and needed after it. known_ids: the clip ids `enqueue` accepts (plus
    `extra_ids`); None asks `motion_fn` and turns its error into a ValueError.
    """

    restarts_on_reset = False
    """A reset resumes the queue where it is (the clip and its time), never rewinds it."""

    def __init__(self, model: mujoco.MjModel, motion_fn: MotionFn, dt_s: float, clips: Iterable[ClipSpec] = (), *,
                 transition_s: float = 0.3, loop: bool = False, at_end: str = "hold", speed: float = 1.0,
                 lookback: int = 12, lookahead: int = 2, known_ids: Sequence[str] | None = None):
        if not (math.isfinite(transition_s) and 0.0 <= transition_s <= 5.0):
            raise ValueError(f"transition_s {transition_s!r} must be in [0, 5] seconds")
        if at_end not in ("hold", "stop"):
            raise ValueError(f"at_end {at_end!r} is not one of hold, stop")
        if not (math.isfinite(speed) and 0.05 <= speed <= 10.0):
            raise ValueError(f"speed {speed!r} must be in [0.05, 10]")
        self.model, self.motion = model, motion_fn
        self.pm = PoseMath(model)
        self.dt, self.speed = float(dt_s), float(speed)
        self.transition_steps = int(round(transition_s / self.dt))
        self.loop, self.at_end = bool(loop), at_end
        self.lookback, self.lookahead = int(lookback), int(lookahead)
        self.known_ids = None if known_ids is None else tuple(known_ids)
        self.extra_ids: set[str] = set()
        """Clips accepted beyond `known_ids` (`ExecutorEnv.register_clip` adds to it)."""
        self.playlist: list[StitchItem] = []
        """Everything enqueued so far, in order: what `begin` (and `loop`) plays again."""
        self.queue: deque[StitchItem] = deque()
        self.stitches = 0
        self._q = np.zeros((0, model.nq))
        self._segments: list[_Segment] = []
        self._dropped = 0
        self.k = 0
        for c in clips:
            self.enqueue(c)

    # ---- the queue ----

    def enqueue(self, clip: ClipSpec, start_s: float | None = None, end_s: float | None = None) -> StitchItem:
        """Queue a clip (id, `StitchItem` or (id, start, end)) after everything queued; returns
        the item. Raises ValueError for an unknown clip or times outside it."""
        item = self._item(clip, start_s, end_s)
        self.playlist.append(item)
        self.queue.append(item)
        return item

    def _item(self, clip: ClipSpec, start_s: float | None, end_s: float | None) -> StitchItem:
        if isinstance(clip, StitchItem):
            item = clip
        elif isinstance(clip, str):
            item = StitchItem(clip, start_s, end_s)
        else:
            parts = tuple(clip) if isinstance(clip, (tuple, list)) else ()
            if not 1 <= len(parts) <= 3 or not isinstance(parts[0], str):
                raise ValueError(f"a stitch item is a clip id or (clip_id, start_s, end_s), not {clip!r}")
            item = StitchItem(*parts)
        self._check_known(item.clip_id)
        duration = self.motion(item.clip_id).duration_s
        start = 0.0 if item.start_s is None else _seconds(item.start_s)
        end = duration if item.end_s is None else _seconds(item.end_s)
        if not (math.isfinite(start) and math.isfinite(end) and 0.0 <= start < end <= duration + 1e-9):
            raise ValueError(f"clip {item.clip_id!r}: start {item.start_s} s and end {item.end_s} s must satisfy "
                             f"0 <= start < end <= {duration:.3f} s (its duration)")
        return StitchItem(item.clip_id, start, min(end, duration))

    def _check_known(self, clip_id: str) -> None:
        if self.known_ids is None:
            try:
                self.motion(clip_id)
            except Exception as exc:  # NOTE: any loader error means the same thing to the caller
                raise ValueError(f"unknown clip {clip_id!r}: {exc}") from exc
            return
        if clip_id in self.known_ids or clip_id in self.extra_ids:
            return
        few = ", ".join(self.known_ids[:6]) + (", ..." if len(self.known_ids) > 6 else "")
        raise ValueError(f"unknown clip {clip_id!r}; known clips ({len(self.known_ids)}): {few}")

    # ---- the Scheduler contract ----

    def begin(self, rng: np.random.Generator, clip_id: str | None = None, start_s: float | None = None,
              align_to: np.ndarray | None = None) -> None:
        """Restart the program: `clip_id` first when given (from `start_s`), else the playlist's
        head; then the rest of the playlist. Placed under `align_to` (a qpos) when given."""
        self.queue = deque(self.playlist)
        if clip_id:
            head = self.queue.popleft() if self.queue and self.queue[0].clip_id == clip_id else None
            end = head.end_s if head is not None else None
            first = self._item(clip_id, head.start_s if (head is not None and start_s is None) else start_s, end)
        elif self.queue:
            first = self.queue.popleft()
            if start_s is not None:
                first = self._item(first.clip_id, start_s, first.end_s)
        else:
            raise ValueError("the stitch scheduler has nothing to play: enqueue clips first")
        m = self.motion(first.clip_id)
        n = self._steps(first)
        rows = np.arange(-self.lookback - 1, n + 1)
        q = np.atleast_2d(m.qpos(first.start_s + rows * self.dt * self.speed))
        if align_to is not None:
            start = q[self.lookback + 1]
            yaw = heading(quat_to_mat(align_to[3:7])) - heading(quat_to_mat(start[3:7]))
            shift = np.zeros(3)
            shift[:2] = np.asarray(align_to[:2], dtype=np.float64) - (yaw_matrix(yaw) @ start[0:3])[:2]
            q = self._place(q, yaw, shift)
        self._q = q
        self._dropped = 0
        self.k = self.lookback + 1
        self.stitches = 0
        self._segments = [_Segment("clip", 0, first.clip_id, first.start_s - (self.lookback + 1) * self.dt * self.speed,
                                   m.duration_s, len(q))]

    def frame(self, i: int) -> TargetFrame:
        row = self.k + int(i)
        self._ensure(row + 1)
        r = min(max(row - self._dropped, 0), len(self._q) - 1)
        lo, hi = max(r - 1, 0), min(r + 1, len(self._q) - 1)
        v = self.pm.velocity(self._q[lo], self._q[hi], (hi - lo) * self.dt) if hi > lo else np.zeros(self.model.nv)
        return TargetFrame(self._q[r], v)

    def advance(self, rng: np.random.Generator, qpos: np.ndarray) -> bool:
        """One step on. Stitches are continuous by construction: never a reschedule (False)."""
        self.k += 1
        self._ensure(self.k + self.lookahead + 2)
        self._trim()
        return False

    @property
    def done(self) -> bool:
        return self.at_end == "stop" and self._segment().kind == "hold"

    @property
    def clip_id(self) -> str:
        """The clip being played (during a transition: the clip it leads into)."""
        return self._segment().clip_id if self._segments else ""

    @property
    def holding(self) -> bool:
        """The queue ran dry: the last frame is held."""
        return bool(self._segments) and self._segment().kind == "hold"

    def status(self) -> dict:
        seg = self._segment()
        into = self.k - seg.start
        t = seg.t0 + into * self.dt * self.speed if seg.kind == "clip" else seg.t0
        left = max(seg.start + seg.rows - 1 - self.k, 0)
        return {"clip_id": seg.clip_id, "clip_time_s": float(t), "clip_duration_s": seg.duration_s, "steps_left": int(left),
                "segment": seg.kind, "queue": [it.clip_id for it in self.queue], "stitches": self.stitches}

    # ---- the FIFO ----

    def _steps(self, item: StitchItem) -> int:
        """Control steps from the item's start to its end (at least one)."""
        return max(int(math.floor((item.end_s - item.start_s) / (self.dt * self.speed) + 1e-9)), 1)

    def _place(self, q: np.ndarray, yaw: float, shift: np.ndarray) -> np.ndarray:
        placed, _ = place(q, np.zeros((len(q), self.model.nv)), yaw, shift)
        return placed

    def _segment(self) -> _Segment:
        """The segment holding row k."""
        for seg in reversed(self._segments):
            if seg.start <= self.k:
                return seg
        return self._segments[0]

    def _ensure(self, row: int) -> None:
        """Append pieces until absolute row `row` exists."""
        while self._dropped + len(self._q) <= row:
            if not self.queue and self.loop and self.playlist:
                self.queue.extend(self.playlist)
            if self.queue:
                self._stitch(self.queue.popleft())
            else:
                self._hold(row + 1 - self._dropped - len(self._q))

    def _hold(self, n: int) -> None:
        last = self._segments[-1]
        if last.kind != "hold":
            self._segments.append(_Segment("hold", self._dropped + len(self._q), last.clip_id, last.t0 + max(last.rows - 1, 0)
                                           * self.dt * self.speed if last.kind == "clip" else last.t0, last.duration_s, 0))
        self._segments[-1].rows += n
        self._q = np.concatenate([self._q, np.repeat(self._q[-1:], n, axis=0)])

    def _stitch(self, item: StitchItem) -> None:
        """Append transition rows and the item's clip rows after the last row (module docstring)."""
        m = self.motion(item.clip_id)
        n = self._steps(item)
        nxt = np.atleast_2d(m.qpos(item.start_s + np.arange(n + 1) * self.dt * self.speed))
        last, before = self._q[-1], self._q[-2] if len(self._q) > 1 else self._q[-1]
        yaw = heading(quat_to_mat(last[3:7])) - heading(quat_to_mat(nxt[0, 3:7]))
        nxt = self._place(nxt, yaw, np.zeros(3))
        v_prev = (last[0:2] - before[0:2]) / self.dt
        v_next = (nxt[1, 0:2] - nxt[0, 0:2]) / self.dt if len(nxt) > 1 else np.zeros(2)
        m_tr = self.transition_steps
        alpha = np.arange(1, m_tr + 2) / (m_tr + 1)
        # NOTE: the root's horizontal path over the transition: velocities blended linearly, so
        # a walk into a run speeds up instead of stopping for the slerp.
        path = last[0:2] + np.cumsum(((1.0 - alpha)[:, None] * v_prev + alpha[:, None] * v_next) * self.dt, axis=0)
        shift = np.zeros(3)
        shift[:2] = path[-1] - nxt[0, 0:2]
        nxt[:, 0:2] += shift[:2]
        start = self._dropped + len(self._q)
        if m_tr > 0:
            tr = self.pm.blend(last, nxt[0], alpha[:-1])
            tr[:, 0:2] = path[:-1]
            self._segments.append(_Segment("transition", start, item.clip_id, item.start_s, m.duration_s, m_tr))
            self._q = np.concatenate([self._q, tr])
            start += m_tr
        self._segments.append(_Segment("clip", start, item.clip_id, item.start_s, m.duration_s, len(nxt)))
        self._q = np.concatenate([self._q, nxt])
        self.stitches += 1

    def _trim(self, keep_extra: int = 240) -> None:
        """Drop rows long past (older than the lookback plus `keep_extra`), keeping the array small."""
        old = self.k - self._dropped - self.lookback - 2
        if old > 2 * keep_extra:
            cut = old - keep_extra
            self._q = self._q[cut:]
            self._dropped += cut
            first = self._dropped
            self._segments = [s for i, s in enumerate(self._segments)
                              if i + 1 >= len(self._segments) or self._segments[i + 1].start > first]


def _seconds(value) -> float:
    """A clip time as a float; NaN (refused by the range check after it) for anything that is not a number."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan
