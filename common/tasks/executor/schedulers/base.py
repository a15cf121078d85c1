"""Schedulers: where the executor's target frames come from (UniCon 2020's high level, METHOD.md B
"Schedulers"; DESIGN.md "Schedulers, play and the studio").

The executor task asks its scheduler for target frames only through `Scheduler`: `begin` a
schedule, `frame(i)` for the frame i control steps from now (negative i: the past, for reactive
initialization), `advance` one control step. A frame is a pose and velocity of the character's
own model in the world (`TargetFrame`), so any source (a clip, a stitched queue, a keyboard
generator, poses from video) plugs in without touching the task or retraining the policy.

`DatasetScheduler` is the one training uses (UniCon 5.1): a clip and a start time drawn by a
`ClipManager` (`common/motion/clip_manager.py`: the motion balancer's clips, uniform starts),
rescheduled to another clip and start drawn by it at the clip's end, or, for evaluation,
stopping there. A rescheduled clip is placed where the character is: its root at the
new frame is moved onto the character's horizontal position and heading. UniCon also reschedules
"on deviation": with `max_deviation_m` set, a character whose root drifts farther than that
(horizontally) from the target root gets its schedule re-placed under it.

The other run-time schedulers live in their own modules: `scheduler_stitch.py` (a FIFO of clips
with slerp transitions), `scheduler_keyboard.py` (a kinematic generator steered by keys),
`scheduler_video.py` (3-D joint positions over UDP); `scheduler_factory.make_scheduler` builds
any of them for an `ExecutorEnv` (`ExecutorEnv.use_scheduler` swaps it in).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Protocol, Sequence

import mujoco
import numpy as np

from common.motion.clip_manager import ClipManager
from common.motion.reference import CharacterMotion
from common.tasks.observations import heading, quat_to_mat, yaw_matrix

MotionFn = Callable[[str], CharacterMotion]
"""Returns a clip played on the character's model (cached by the caller)."""


@dataclass(frozen=True)
class TargetFrame:
    """One target frame of the character: qpos `[nq]` and qvel `[nv]` in MuJoCo's layout, world frame."""

    qpos: np.ndarray
    qvel: np.ndarray


class Scheduler(Protocol):
    clip_id: str
    """What is being tracked now, by name (a clip id; "video" for a live source)."""
    restarts_on_reset: bool
    """What an episode's reset does to the schedule (`ExecutorEnv.reset`): True, `begin` it
    anew (the dataset scheduler: a new draw every episode, as training needs); False, resume it
    where it is, the character put on the current target frame (stitch, keyboard, video: a
    reset never rewinds the queue, the key script or the clock). The first reset after
    `ExecutorEnv.use_scheduler` begins any scheduler."""

    def begin(self, rng: np.random.Generator, clip_id: str | None = None, start_s: float | None = None,
              align_to: np.ndarray | None = None) -> None:
        """Start a schedule: a clip (drawn when None) from `start_s` (random when None), placed at
        the character's pose `align_to` (qpos) when given, else where the clip has it."""

    def frame(self, i: int) -> TargetFrame:
        """The target frame i control steps from now (i may be negative)."""

    def advance(self, rng: np.random.Generator, qpos: np.ndarray) -> bool:
        """Move one control step on; `qpos` is the character's pose now. Returns True when the
        schedule jumped (a reschedule), so the caller knows the targets are discontinuous."""

    @property
    def done(self) -> bool:
        """The schedule has no next frame (a stopping scheduler at its end)."""

    def status(self) -> dict:
        """What is being tracked, for logs, evaluation and the live status: at least clip_id
        and clip_time_s (seconds into that clip; a live source: its clock)."""


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def place(qpos: np.ndarray, qvel: np.ndarray, yaw: float, shift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frames `[N, nq]`, `[N, nv]` rotated by `yaw` about world z, then shifted by `shift` `[3]`.
    A free joint's linear velocity is in the world frame (rotated), its angular one in the body
    frame (unchanged)."""
    rot = yaw_matrix(yaw)
    q, v = qpos.copy(), qvel.copy()
    q[:, 0:3] = q[:, 0:3] @ rot.T + shift
    yq = yaw_quat(yaw)
    for row in q:
        out = np.zeros(4)
        mujoco.mju_mulQuat(out, yq, row[3:7])
        row[3:7] = out
    v[:, 0:3] = v[:, 0:3] @ rot.T
    return q, v


class DatasetScheduler:
    """Random clip and frame from a clip set, rescheduled (or stopped) at the clip's end
    (UniCon 2020, METHOD.md B "Schedulers": the dataset scheduler).

    `clips` decides which clip and start each (re)schedule plays: a `ClipManager` (then
    `probabilities` is None), or clip ids with their `probabilities`, made into one
    (`ClipManager.with_probabilities`, durations from `motion`). Starts leave at least three
    control steps of the clip after them, so a schedule is never empty.

    Deviation (UniCon: "reschedule at the end or on deviation"; opt-in, off by default):
    with `max_deviation_m` set, `advance` reschedules as soon as the character's root is
    farther than that from the target root in the horizontal plane. `on_deviation` says how:
    "realign" (default) keeps the clip and its time and re-places the rest of it under the
    character (root onto its horizontal position and heading), "redraw" draws a new clip and
    frame as at a clip's end. The check waits `deviation_grace_steps` after every (re)start,
    so a character that starts off its target (reactive initialization) is not rescheduled at
    once. Counted in `deviation_reschedules` (also in `reschedules`).

    The frames of the current schedule are sampled once on the control grid t0 + k dt speed
    (vectorized: per-step slerps in Python would cost more than the physics), from
    `lookback` steps before the start to the clip's end plus the lookahead; velocities are
    differences over +-`velocity_window` control steps (`CharacterMotion.qvel_at`: centred inside the clip,
    one-sided at its first and last frames), in real time, so a faster playback has faster
    targets.
    """

    restarts_on_reset = True
    """Every episode's reset begins a new draw (training's episodes are independent starts)."""

    def __init__(self, model: mujoco.MjModel, motion: MotionFn, clips: ClipManager | Sequence[str],
                 probabilities: np.ndarray | None, dt_s: float, *, speed: float = 1.0, at_end: str = "reschedule",
                 lookback: int = 12, lookahead: int = 2,
                 max_deviation_m: float | None = None, on_deviation: str = "realign", deviation_grace_steps: int = 10,
                 velocity_window: int = 1, kinematics: Callable[[np.ndarray, np.ndarray], Any] | None = None):
        if isinstance(clips, ClipManager):
            if probabilities is not None or clips.duration_s is None:
                raise ValueError("DatasetScheduler: give a ClipManager that knows clip durations, and probabilities None")
        elif not clips:
            raise ValueError("DatasetScheduler needs at least one clip")
        else:
            clips = ClipManager.with_probabilities(clips, probabilities, lambda c: motion(c).duration_s)
        if at_end not in ("reschedule", "stop"):
            raise ValueError(f"at_end {at_end!r} is not one of reschedule, stop")
        if max_deviation_m is not None and not (math.isfinite(max_deviation_m) and max_deviation_m > 0):
            raise ValueError(f"max_deviation_m {max_deviation_m!r} must be a positive distance in metres (or None: off)")
        if on_deviation not in ("realign", "redraw"):
            raise ValueError(f"on_deviation {on_deviation!r} is not one of realign, redraw")
        self.max_deviation_m = None if max_deviation_m is None else float(max_deviation_m)
        self.on_deviation = on_deviation
        self.deviation_grace_steps = int(deviation_grace_steps)
        self.deviation_reschedules = 0
        self.model, self.motion = model, motion
        self.clips = clips
        self.clip_ids = clips.clip_ids
        self.dt, self.speed, self.at_end = float(dt_s), float(speed), at_end
        if isinstance(velocity_window, bool) or not (isinstance(velocity_window, int) and 1 <= velocity_window <= 30):
            raise ValueError(f"velocity_window {velocity_window!r} must be a whole number of control steps in 1 .. 30")
        self.velocity_window = velocity_window
        self.kinematics = kinematics
        self._kin: Any = None
        self._kin_lo = self._kin_hi = 0
        self.lookback, self.lookahead = int(lookback), int(lookahead)
        self.clip_id = ""
        self._done = False
        self.reschedules = 0
        self.extra_ids: set[str] = set()
        """Clips that may be begun by name but are never drawn (evaluation on unseen clips)."""

    # ---- the Scheduler contract ----

    def begin(self, rng: np.random.Generator, clip_id: str | None = None, start_s: float | None = None,
              align_to: np.ndarray | None = None) -> None:
        if clip_id is None or clip_id == "":
            clip_id = self.clips.draw_clip(rng)
        elif clip_id not in self.clip_ids and clip_id not in self.extra_ids:
            raise ValueError(f"clip {clip_id!r} is not in this scheduler's set ({len(self.clip_ids)} clips: "
                             f"{', '.join(self.clip_ids[:6])}{', ...' if len(self.clip_ids) > 6 else ''})")
        m = self.motion(clip_id)
        duration = m.duration_s
        if start_s is None:
            start_s = self.clips.draw_start(rng, clip_id, min_left_s=3 * self.dt * self.speed)
        if not 0.0 <= start_s <= duration:
            raise ValueError(f"start {start_s} s is outside clip {clip_id!r} (0 .. {duration:.3f} s)")
        self.clip_id, self._motion, self.t0 = clip_id, m, float(start_s)
        self.k = 0
        self._done = False
        steps_left = int(math.floor((duration - start_s) / (self.dt * self.speed) + 1e-9))
        self.last_k = max(steps_left, 1)
        self._first_row = -self.lookback - 1
        self._rows = self.last_k + self.lookahead + 2 - self._first_row
        q, v = self._sample(0, min(self._rows, self.lookback + 1 + self.CHUNK_ROWS))
        self._yaw, self._shift = 0.0, np.zeros(3)
        if align_to is not None:
            start = q[self.lookback + 1]
            self._yaw = heading(quat_to_mat(align_to[3:7])) - heading(quat_to_mat(start[3:7]))
            self._shift[:2] = align_to[:2] - (yaw_matrix(self._yaw) @ start[0:3])[:2]
        self._q, self._v = place(q, v, self._yaw, self._shift)
        self._row0 = self.lookback + 1
        self._kin, self._kin_lo, self._kin_hi = None, 0, 0

    CHUNK_ROWS = 64
    """Rows of the schedule sampled at a time: `begin` samples the first ones, `frame` the next
    when it reaches them. Sampling the whole rest of a clip at every start cost 2.4 ms (per-row
    loops in `qvel_at` and `place`) when most training episodes end within 40 steps. Each row
    depends on its own time only, so the frames are the same however they are chunked."""

    def _sample(self, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
        """Unplaced qpos and qvel of schedule rows [lo, hi) (row `lookback + 1` is the start)."""
        times = self.t0 + np.arange(self._first_row + lo, self._first_row + hi) * self.dt * self.speed
        q = np.atleast_2d(self._motion.qpos(times))
        # NOTE: differences over +-velocity_window control steps of clip time, kept inside the clip at its ends
        # (a centred window over the held first/last frame saw half the motion: a run's start
        # frame got half its speed); times `speed` (clip seconds per real second): real-time velocities.
        v = self._motion.qvel_at(times, self.velocity_window * self.dt * self.speed) * self.speed
        return q, v

    KINEMATICS_ROWS = 16
    """Rows of the schedule whose `kinematics` are computed at a time (`kinematics_at`)."""

    def row(self, i: int) -> int:
        """The schedule row of the frame i control steps from now (sampled if it was not yet)."""
        # NOTE: min/max on the int, not np.clip: a scalar np.clip cost 10 us, a tenth of the executor's step
        row = min(max(self._row0 + self.k + int(i), 0), self._rows - 1)
        if row >= len(self._q):
            q, v = place(*self._sample(len(self._q), min(self._rows, row + 1 + self.CHUNK_ROWS)), self._yaw, self._shift)
            self._q, self._v = np.concatenate([self._q, q]), np.concatenate([self._v, v])
        return row

    def frame(self, i: int) -> TargetFrame:
        row = self.row(i)
        return TargetFrame(self._q[row], self._v[row])

    def kinematics_at(self, offsets: Sequence[int]) -> Any:
        """`kinematics(qpos [R, nq], qvel [R, nv])` (the callable given at construction, e.g. the
        executor's body kinematics of each frame) of the frames `offsets` control steps from now,
        indexed out of a table of `KINEMATICS_ROWS` schedule rows computed at once when a frame
        outside it is asked for (a step asks for the next rows in turn, so each row is computed
        once per schedule). The table holds what `kinematics` gives each frame alone."""
        if self.kinematics is None:
            raise ValueError("this DatasetScheduler was built without a kinematics function")
        rows = np.array([self.row(i) for i in offsets])
        lo, hi = int(rows.min()), int(rows.max()) + 1
        if lo < self._kin_lo or hi > self._kin_hi:
            hi = min(self._rows, max(hi, lo + self.KINEMATICS_ROWS))
            self.row(hi - 1 - self._row0 - self.k)
            self._kin = self.kinematics(self._q[lo:hi], self._v[lo:hi])
            self._kin_lo, self._kin_hi = lo, hi
        return self._kin[rows - self._kin_lo]

    def advance(self, rng: np.random.Generator, qpos: np.ndarray) -> bool:
        self.k += 1
        if self.k < self.last_k:
            return self._deviation_reschedule(rng, qpos)
        if self.at_end == "stop":
            self._done = True
            return False
        self.reschedules += 1
        self.begin(rng, None, None, align_to=qpos)
        return True

    def deviation_m(self, qpos: np.ndarray) -> float:
        """Horizontal distance (m) between the character's root (`qpos`) and the target root now."""
        return float(np.linalg.norm(np.asarray(qpos[0:2], dtype=np.float64) - self.frame(0).qpos[0:2]))

    def _deviation_reschedule(self, rng: np.random.Generator, qpos: np.ndarray) -> bool:
        if self.max_deviation_m is None or self.k < self.deviation_grace_steps:
            return False
        if not self.deviation_m(qpos) > self.max_deviation_m:
            return False
        self.reschedules += 1
        self.deviation_reschedules += 1
        if self.on_deviation == "redraw":
            self.begin(rng, None, None, align_to=qpos)
        else:
            t = min(self.t0 + self.k * self.dt * self.speed, self._motion.duration_s)
            self.begin(rng, self.clip_id, t, align_to=qpos)
        return True

    def body_changed(self) -> None:
        """The character's body changed mid-schedule (`ExecutorEnv.set_shape`): re-read the clip
        from `motion` (now the clip on the new body) and resample every row sampled so far,
        keeping the clip, its time, the step and the placement's heading, the placement moved
        horizontally so the target root now is where the old one was (a clip retargeted onto
        longer legs strides farther: without the move the target would jump ahead by the
        difference of the strides walked so far)."""
        if not self.clip_id:
            return
        old_root = self.frame(0).qpos[0:3].copy()
        self._motion = self.motion(self.clip_id)
        q, v = self._sample(0, len(self._q))
        self._q, self._v = place(q, v, self._yaw, self._shift)
        move = old_root - self.frame(0).qpos[0:3]
        move[2] = 0.0
        self._shift = self._shift + move
        self._q[:, 0:3] += move
        self._kin, self._kin_lo, self._kin_hi = None, 0, 0

    @property
    def done(self) -> bool:
        return self._done

    def status(self) -> dict:
        return {"clip_id": self.clip_id, "clip_time_s": self.t0 + self.k * self.dt * self.speed,
                "clip_duration_s": self._motion.duration_s, "steps_left": self.last_k - self.k}
