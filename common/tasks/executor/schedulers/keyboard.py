"""Keyboard control: a kinematic generator turns direction, speed and style commands into target
frames (UniCon 2020, METHOD.md B "Schedulers": "keyboard: a kinematic generator turns
direction/speed/style into target frames").

    s = KeyboardScheduler(model, motion_fn, dt_s, style="walk", script=[(1.0, "left"), (3.0, "faster")])
    s.begin(rng, align_to=character_qpos)
    s.command("style:run")                 # or "left", "right", "faster", "slower", "stop", "walk", "run"

The generator plays the style's locomotion clip cyclically (`locomotion_styles`: every humanoid
clip labelled root/locomotion/..., named by its id: walk, run, crawl, zombie_walk, mass_walk,
mass_run; and every style of the Bandai Namco walks, runs and dashes, named `<style>_<content>`:
happy_walk, tired_run, proud_dash, ...; a take of several strides loops over its closest-posed
span, `_loop_rows`):

- One cycle is sampled once on the control grid (`_Cycle`, vectorised), turned so the clip's
  direction of travel (its root displacement over the clip) is +x, and its seam closed: the
  difference between the last and first frame (mocap rarely closes, see the NOTE in
  `ExecutorEnv._motion`) is spread over `seam_s` on either side of the seam, half each, so the
  loop has no jump. The root's horizontal position is not taken from the clip but integrated
  from its per-step displacements, which re-aligns the root every cycle.
- Each control step the root moves by that step's displacement, scaled by the speed factor and
  turned to the heading; the joints, root height and root tilt are the clip's.
- Direction: "left"/"right" change the commanded heading by `turn_step_rad`; the heading follows
  at most `max_turn_rate` rad/s, so a turn is spread over several steps.
- Speed: "faster"/"slower" move through `SPEED_FACTORS` (x the clip's own speed); "stop" is 0,
  which keeps stepping in place (the clips have no idle); the factor follows the command at
  most `max_accel` per second.
- Style: "style:<name>" (or "walk"/"run") cross-fades to the other clip over `blend_s`, entering
  it at the frame closest to the current pose, with the root displacement blended too.

Future frames (the executor's lookahead) are predicted with the commands as they are; past
frames are those generated (at `begin`, synthesized backwards). Velocities are centred
differences of neighbouring frames (`mj_differentiatePos`).

An episode's reset resumes the generator (`restarts_on_reset` False): the style, heading, speed
and the script's clock go on, the character is put on the current frame; only `begin` (the
first reset after `ExecutorEnv.use_scheduler`) restarts the script.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Iterable

import mujoco
import numpy as np

from common.motion.library import clips_for
from common.motion.manifest import Manifest, load_manifest, unicon_take_split
from common.tasks.observations import JointLayout, heading, quat_to_mat
from common.tasks.executor.schedulers.pose_blend import PoseMath
from common.tasks.executor.schedulers.base import MotionFn, TargetFrame, place, yaw_quat

SPEED_FACTORS = (0.0, 0.5, 0.75, 1.0, 1.25, 1.5)
"""Speed levels "faster"/"slower" step through, as factors of the style clip's own root speed."""
KEYS = ("left", "right", "faster", "slower", "stop", "walk", "run", "style:<name>")
"""The commands `KeyboardScheduler.command` accepts ("walk"/"run": shortcuts for the styles)."""


BANDAI_LOCOMOTION = ("walk", "run", "dash")
"""The Bandai Namco contents that travel: each of their styles is a keyboard style."""


def locomotion_styles(character: str = "humanoid", split_seed: int = 0) -> dict[str, str]:
    """Style name -> clip id of every locomotion style of `character`'s library: each clip
    labelled root/locomotion/... named by its id's last part without 'humanoid3d_' (walk, run,
    crawl, zombie_walk, mass_walk, mass_run), then each Bandai Namco walk, run and dash style
    (labels root/bandai/<content>/<style>) named `<style>_<content>` (happy_walk, tired_run,
    proud_dash, ...), played from its first take in the executor's training split (seed
    `split_seed`, `unicon_take_split`), else its first take."""
    out: dict[str, str] = {}
    takes: dict[str, list[str]] = {}
    bandai: list[str] = []
    for clip_id, label in clips_for(character):
        if label.startswith("root/locomotion/"):
            out[clip_id.split("/")[-1].removeprefix("humanoid3d_")] = clip_id
        parts = label.split("/")
        if parts[1:2] == ["bandai"]:
            bandai.append(clip_id)
            if len(parts) == 4 and parts[2] in BANDAI_LOCOMOTION:
                takes.setdefault(f"{parts[3]}_{parts[2]}", []).append(clip_id)
    if takes:
        trained = _trained_takes(bandai, split_seed)
        for name in sorted(takes):
            ids = sorted(takes[name])
            out[name] = next((c for c in ids if c in trained), ids[0])
    return out


def _trained_takes(clip_ids: list[str], split_seed: int) -> set[str]:
    """Those of `clip_ids` (every Bandai Namco take of the character, as the executor splits
    them: `common.tasks.executor.env.labelled_clips`) in the training split."""
    manifest = load_manifest()
    by_take = unicon_take_split(Manifest(tuple(manifest.by_id(c) for c in clip_ids)), seed=split_seed)
    return set(by_take.train)


LOOP_SEARCH_S = 2.5
"""A style clip longer than this is a take of several strides (with its own start and end), not
one cycle: its loop is the span between the two frames, one in its first and one in its last
third, whose poses are closest (`_loop_rows`)."""


def _loop_rows(joints: np.ndarray, height: np.ndarray) -> tuple[int, int]:
    """Rows (i, j) of the best loop in a take sampled on the control grid (`joints` `[R, nu]`
    joint vectors, `height` `[R]` root heights): i in the first third, j in the last third, the
    pair whose joint vectors and root heights differ least."""
    r = len(joints)
    first, last = np.arange(0, r // 3), np.arange(r - r // 3, r)
    cost = np.linalg.norm(joints[first, None, :] - joints[None, last, :], axis=-1)
    cost += 10.0 * np.abs(height[first, None] - height[None, last])
    a, b = np.unravel_index(int(np.argmin(cost)), cost.shape)
    return int(first[a]), int(last[b])


@dataclass(frozen=True)
class _Cycle:
    """One style's clip as a closed cycle on the control grid, travelling along +x.

    q `[N, nq]` frames (root x, y unused), step `[N, 2]` the root's horizontal displacement from
    row r to r + 1, joints `[N, nu]` joint vectors (to find the closest frame on a style change),
    speed_mps the clip's mean horizontal root speed, period_s its duration."""

    clip_id: str
    q: np.ndarray
    step: np.ndarray
    joints: np.ndarray
    speed_mps: float
    period_s: float

    @property
    def n(self) -> int:
        return len(self.q)


@dataclass(frozen=True)
class _State:
    """The generator at one control step."""

    style: str
    row: int
    xy: np.ndarray
    yaw: float
    speed: float
    prev_style: str | None = None
    prev_row: int = 0
    fade: int = 0
    """Steps left of the cross-fade from prev_style (0: none)."""


class KeyboardScheduler:
    """A kinematic locomotion generator steered by keys (UniCon 2020, METHOD.md B "Schedulers":
    keyboard); see the module docstring.

    model/motion_fn/dt_s: the character's model, clip id -> `CharacterMotion`, control step (an
    `ExecutorEnv`'s `ref_model`, `_motion`, `dt`). styles: style -> clip id (default:
    `locomotion_styles()`). script: timed commands [(seconds after `begin`, key), ...].
    lookback/lookahead: frames kept before / predicted after frame 0.
    """

    restarts_on_reset = False
    """A reset resumes the generator and the script's clock, never restarts them."""

    def __init__(self, model: mujoco.MjModel, motion_fn: MotionFn, dt_s: float, *, style: str = "walk",
                 styles: dict[str, str] | None = None, speed: float = 1.0, heading_rad: float = 0.0,
                 turn_step_rad: float = math.radians(30.0), max_turn_rate: float = math.radians(120.0), max_accel: float = 2.0,
                 blend_s: float = 0.3, seam_s: float = 0.15, script: Iterable[tuple[float, str]] = (),
                 lookback: int = 12, lookahead: int = 2):
        self.model, self.motion = model, motion_fn
        self.pm = PoseMath(model)
        self.layout = JointLayout(model)
        self.dt = float(dt_s)
        self.styles = dict(locomotion_styles() if styles is None else styles)
        if not self.styles:
            raise ValueError("the keyboard scheduler needs at least one locomotion style")
        self._check_style(style)
        if not (math.isfinite(speed) and 0.0 <= speed <= max(SPEED_FACTORS)):
            raise ValueError(f"speed factor {speed!r} must be in [0, {max(SPEED_FACTORS)}]")
        self.initial_style, self.initial_speed, self.initial_heading = style, float(speed), float(heading_rad)
        self.turn_step, self.max_turn_rate, self.max_accel = float(turn_step_rad), float(max_turn_rate), float(max_accel)
        self.blend_steps = max(int(round(blend_s / self.dt)), 1)
        self.seam_s = float(seam_s)
        self.lookback, self.lookahead = int(lookback), int(lookahead)
        self.script = self._check_script(script)
        self._cycles: dict[str, _Cycle] = {}
        self.k = 0
        self.log: list[tuple[int, str]] = []
        """(control step, key) of every command applied since `begin`."""
        self._state: _State | None = None

    @classmethod
    def from_script(cls, model: mujoco.MjModel, motion_fn: MotionFn, dt_s: float, script: Iterable[tuple[float, str]],
                    **options) -> "KeyboardScheduler":
        """A scheduler that plays `script`, [(seconds after `begin`, key), ...], e.g. for a video."""
        return cls(model, motion_fn, dt_s, script=script, **options)

    # ---- commands ----

    def command(self, key: str) -> None:
        """Apply one key now (see `KEYS`); raises ValueError naming an unknown key or style."""
        key = self._check_key(key)
        self._require_begun()
        st = self._state
        if key == "left":
            self.target_heading += self.turn_step
        elif key == "right":
            self.target_heading -= self.turn_step
        elif key == "faster":
            self.target_speed = next((f for f in SPEED_FACTORS if f > self.target_speed + 1e-9), max(SPEED_FACTORS))
        elif key == "slower":
            self.target_speed = next((f for f in reversed(SPEED_FACTORS) if f < self.target_speed - 1e-9), 0.0)
        elif key == "stop":
            self.target_speed = 0.0
        else:
            style = key.removeprefix("style:")
            if style != st.style:
                self._state = self._switch(st, style)
            if self.target_speed == 0.0 and key in ("walk", "run"):
                self.target_speed = 1.0
        self.log.append((self.k, key))
        self._invalidate()

    def _check_key(self, key: str) -> str:
        if not isinstance(key, str):
            raise ValueError(f"key {key!r} is not one of {', '.join(KEYS)}")
        key = key.strip().lower()
        if key in ("walk", "run"):
            if key not in self.styles:
                raise ValueError(f"key {key!r}: no {key!r} style here; styles: {', '.join(self.styles)}")
            return key
        if key.startswith("style:"):
            self._check_style(key.removeprefix("style:"))
            return key
        if key not in KEYS:
            raise ValueError(f"key {key!r} is not one of {', '.join(KEYS)} (styles: {', '.join(self.styles)})")
        return key

    def _check_style(self, style: str) -> None:
        if style not in self.styles:
            raise ValueError(f"style {style!r} is not one of {', '.join(self.styles)}")

    def _check_script(self, script: Iterable[tuple[float, str]]) -> tuple[tuple[float, str], ...]:
        out = []
        for entry in script:
            try:
                t, key = entry
                t = float(t)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"script entry {entry!r} is not (seconds, key)") from exc
            if not (math.isfinite(t) and t >= 0.0):
                raise ValueError(f"script entry {entry!r}: seconds must be finite and >= 0")
            out.append((t, self._check_key(key)))
        return tuple(sorted(out, key=lambda e: e[0]))

    # ---- the Scheduler contract ----

    def begin(self, rng: np.random.Generator, clip_id: str | None = None, start_s: float | None = None,
              align_to: np.ndarray | None = None) -> None:
        """Start the generator in the initial style and speed (clip_id is ignored), `start_s`
        seconds into the style's cycle (0 when None), at the character's pose `align_to` (root
        position and heading) when given, else at the origin facing `heading_rad`; the script
        restarts."""
        cyc = self._cycle(self.initial_style)
        row = 0 if start_s is None else int(round(float(start_s) / self.dt)) % cyc.n
        xy, yaw = np.zeros(2), self.initial_heading
        if align_to is not None:
            xy = np.asarray(align_to[0:2], dtype=np.float64).copy()
            yaw = heading(quat_to_mat(align_to[3:7])) - heading(quat_to_mat(cyc.q[row, 3:7]))
        self._state = _State(self.initial_style, row, xy, float(yaw), self.initial_speed)
        self.target_heading, self.target_speed = float(yaw), self.initial_speed
        self.k = 0
        self.log = []
        self._script_next = 0
        self._past: deque[np.ndarray] = deque(maxlen=self.lookback + 3)
        back = self._state
        for _ in range(self.lookback + 2):
            back = self._back(back)
            self._past.append(self._pose(back))
        self._invalidate()
        self._run_script()

    def frame(self, i: int) -> TargetFrame:
        i = int(i)
        q = self._window(i - 1, i + 1)
        return TargetFrame(q[1], self.pm.velocity(q[0], q[2], 2.0 * self.dt))

    def advance(self, rng: np.random.Generator, qpos: np.ndarray) -> bool:
        """One step on (the character's pose is not used: the generator is kinematic). False:
        commands change the targets smoothly, never by a jump."""
        self._require_begun()
        self._past.appendleft(self._pose(self._state))
        self._state = self._step(self._state)
        self.k += 1
        self._invalidate()
        self._run_script()
        return False

    def body_changed(self) -> None:
        """The character's body changed (`ExecutorEnv.set_shape`): the style cycles are rebuilt
        from `motion` (now the clips on the new body) and the generator goes on from its state
        (position, heading, speed factor, commands), its rows wrapped into the new cycles and
        its past and future recomputed on them (the root speed follows the new body's stride)."""
        self._cycles.clear()
        if self._state is None:
            return
        st = self._state
        rows = {"row": st.row % self._cycle(st.style).n}
        if st.prev_style is not None:
            rows["prev_row"] = st.prev_row % self._cycle(st.prev_style).n
        self._state = replace(st, **rows)
        self._past.clear()
        back = self._state
        for _ in range(self.lookback + 2):
            back = self._back(back)
            self._past.append(self._pose(back))
        self._invalidate()

    @property
    def done(self) -> bool:
        return False

    @property
    def clip_id(self) -> str:
        return self.styles[self._state.style] if self._state is not None else self.styles[self.initial_style]

    @property
    def style(self) -> str:
        return self._state.style if self._state is not None else self.initial_style

    @property
    def heading_rad(self) -> float:
        """The generator's heading now (rad): its direction of travel."""
        return self._state.yaw

    @property
    def speed_mps(self) -> float:
        """The commanded horizontal root speed now (m/s): the factor x the style's own speed."""
        return self._state.speed * self._cycle(self._state.style).speed_mps

    def status(self) -> dict:
        self._require_begun()
        st = self._state
        cyc = self._cycle(st.style)
        return {"clip_id": cyc.clip_id, "clip_time_s": st.row * cyc.period_s / cyc.n, "clip_duration_s": cyc.period_s,
                "steps_left": 0, "style": st.style, "heading_rad": st.yaw, "target_heading_rad": self.target_heading,
                "speed_factor": st.speed, "target_speed_factor": self.target_speed, "speed_mps": self.speed_mps}

    # ---- the generator ----

    def _require_begun(self) -> None:
        if self._state is None:
            raise RuntimeError("call begin() before using the keyboard scheduler")

    def _run_script(self) -> None:
        now = self.k * self.dt
        while self._script_next < len(self.script) and self.script[self._script_next][0] <= now + 1e-9:
            self.command(self.script[self._script_next][1])
            self._script_next += 1

    def _invalidate(self) -> None:
        self._future: list[np.ndarray] = [self._pose(self._state)]
        self._future_state = self._state

    def _window(self, lo: int, hi: int) -> np.ndarray:
        """Rows for frames lo .. hi `[hi - lo + 1, nq]`: the past (clamped to the oldest kept),
        now, and the future predicted with the current commands."""
        while len(self._future) <= hi:
            self._future_state = self._step(self._future_state)
            self._future.append(self._pose(self._future_state))
        rows = []
        for i in range(lo, hi + 1):
            rows.append(self._future[i] if i >= 0 else self._past[min(-i - 1, len(self._past) - 1)])
        return np.stack(rows)

    def _cycle(self, style: str) -> _Cycle:
        if style not in self._cycles:
            self._cycles[style] = self._build_cycle(self.styles[style])
        return self._cycles[style]

    def _build_cycle(self, clip_id: str) -> _Cycle:
        """The clip sampled on the control grid, travelling along +x, its seam closed."""
        m = self.motion(clip_id)
        period = m.duration_s
        n = max(int(round(period / self.dt)), 4)
        q = np.atleast_2d(m.qpos(np.arange(n + 1) * period / n))
        if period > LOOP_SEARCH_S:  # a take of several strides: its closest-posed span
            i, j = _loop_rows(self.layout.to_vector(q), q[:, 2])
            q, n, period = q[i : j + 1], j - i, (j - i) * period / n
        travel = q[-1, 0:2] - q[0, 0:2]
        # NOTE: the clip's direction of travel is its frame: a root's own heading sways within a
        # stride and means nothing for a crawl (the pelvis's forward axis points at the floor).
        yaw0 = math.atan2(travel[1], travel[0]) if np.linalg.norm(travel) > 0.05 else heading(quat_to_mat(q[0, 3:7]))
        q, _ = place(q, np.zeros((n + 1, self.model.nv)), -yaw0, np.zeros(3))
        step = np.diff(q[:, 0:2], axis=0)
        seam = self.pm.difference(q[-1], q[0])
        seam[0:2] = 0.0
        w = min(max(int(round(self.seam_s / self.dt)), 1), n // 3)
        frac = np.zeros(n + 1)
        r = np.arange(n + 1)
        tail = r >= n - w
        frac[tail] = 0.5 * (r[tail] - (n - w)) / w
        head = r <= w
        frac[head] = -0.5 * (1.0 - r[head] / w)
        q = self.pm.normalized(self.pm.add(q, seam, frac))[:n]
        speed = float(np.linalg.norm(travel) / period)
        return _Cycle(clip_id, q, step, self.layout.to_vector(q), speed, period)

    def _pose(self, st: _State) -> np.ndarray:
        """The qpos of a generator state: the cycle row turned to the heading at its position
        (cross-faded from the previous style while a style change lasts)."""
        q = self._placed(self._cycle(st.style).q[st.row], st)
        if st.fade > 0 and st.prev_style is not None:
            old = self._placed(self._cycle(st.prev_style).q[st.prev_row], st)
            q = self.pm.blend(old, q, 1.0 - st.fade / (self.blend_steps + 1))
        return q

    def _placed(self, row: np.ndarray, st: _State) -> np.ndarray:
        q = row.copy()
        q[0:2] = st.xy
        mujoco.mju_mulQuat(q[3:7], yaw_quat(st.yaw), row[3:7])
        return q

    def _displacement(self, st: _State) -> np.ndarray:
        """The root's horizontal displacement (cycle frame) from this state's row to the next."""
        d = self._cycle(st.style).step[st.row]
        if st.fade > 0 and st.prev_style is not None:
            a = 1.0 - st.fade / (self.blend_steps + 1)
            d = (1.0 - a) * self._cycle(st.prev_style).step[st.prev_row] + a * d
        return d

    def _step(self, st: _State) -> _State:
        """The state one control step later under the current commands."""
        c, s = math.cos(st.yaw), math.sin(st.yaw)
        d = self._displacement(st)
        xy = st.xy + st.speed * np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])
        turn = float(np.clip(self.target_heading - st.yaw, -self.max_turn_rate * self.dt, self.max_turn_rate * self.dt))
        accel = self.max_accel * self.dt
        speed = float(np.clip(self.target_speed, st.speed - accel, st.speed + accel))
        n = self._cycle(st.style).n
        prev_row = (st.prev_row + 1) % self._cycle(st.prev_style).n if st.prev_style is not None else 0
        return replace(st, row=(st.row + 1) % n, xy=xy, yaw=st.yaw + turn, speed=speed, prev_row=prev_row,
                       fade=max(st.fade - 1, 0))

    def _back(self, st: _State) -> _State:
        """The state one step earlier at constant heading and speed (the past at `begin`)."""
        cyc = self._cycle(st.style)
        row = (st.row - 1) % cyc.n
        d = cyc.step[row]
        c, s = math.cos(st.yaw), math.sin(st.yaw)
        xy = st.xy - st.speed * np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])
        return replace(st, row=row, xy=xy)

    def _switch(self, st: _State, style: str) -> _State:
        """Start a cross-fade into `style`, entering its cycle at the frame closest to the pose now."""
        now = self.layout.to_vector(self._cycle(st.style).q[st.row])
        new = self._cycle(style)
        row = int(np.argmin(np.sum((new.joints - now) ** 2, axis=1)))
        return replace(st, style=style, row=row, prev_style=st.style, prev_row=st.row, fade=self.blend_steps)
