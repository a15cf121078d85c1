"""The studio's engine, without any web part: one `LiveSession` stepped in real time by a
background thread, steered only through a command queue.

Everything a user does (a slider, a button, a typed value) becomes a command that the loop thread
applies between two control steps, so the session is only ever touched by that thread. A command
that fails (a `ValueError` from `LiveSession`, a missing scheduler, anything else) is counted in
`errors` and its message becomes the status line; the loop keeps stepping. Loading another
checkpoint takes seconds, so it runs in a thread of its own and the finished session is swapped in
between two steps (`generation` counts the swaps, so the web page knows to rebuild its controls).
With `watched` (the studio: a browser is connected), the loop does not step while nobody watches:
an unwatched studio idles instead of simulating for no one (measured: 29% of a core -> 0.1%).
"""

from __future__ import annotations

import collections
import concurrent.futures
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from learner.live.session import AGENTS, SCHEDULERS, SHAPE_FIXED, LiveSession, shape_pair, video_status

PRETRAINED = Path(__file__).resolve().parents[1] / "pretrained"
KEYS = ("left", "right", "faster", "slower", "stop")
"""The keyboard scheduler's commands besides `style:<name>`."""
HISTORY_S = 10.0
"""Seconds of reward terms kept for the plots."""
MAX_LAG_S = 0.25
"""Behind real time by more than this (a slow machine, a morph), the loop drops the backlog
instead of racing to catch up."""
IDLE_WAIT_S = 0.25
"""With `watched` set and nobody watching, the loop wakes this often (commands are still applied)."""


def pretrained_checkpoints() -> dict[str, str]:
    """name -> path of every shipped checkpoint (learner/pretrained/<name>/state.pt)."""
    return {p.name: str(p) for p in sorted(PRETRAINED.iterdir()) if (p / "state.pt").is_file()}


def parse_shape_text(text: str) -> dict[str, float]:
    """'global_z=1.2 Pelvis_x=0.9' (spaces or commas between pairs) -> {name: value}."""
    out: dict[str, float] = {}
    for item in text.replace(",", " ").split():
        name, number = shape_pair(item)
        out[name] = number
    if not out:
        raise ValueError("type NAME=VALUE pairs, e.g. global_z=1.2")
    return out


def _raiser(exc: BaseException) -> Callable[[], None]:
    """A command that fails with `exc` on the loop thread (so it is counted and shown there)."""
    def apply() -> None:
        raise exc
    return apply


@dataclass
class Command:
    label: str
    apply: Callable[[], str | None]
    """Runs on the loop thread; returns a message for the status line (None: keep it)."""
    shape: dict[str, float] | None = None
    """A shape command: consecutive ones are merged into one morph."""
    quiet: bool = False
    """Not a user's command (a read): not counted."""


class StudioCore:
    """A session, its real-time loop and its command queue (see the module docstring)."""

    def __init__(self, checkpoint: str, agent: str = "policy", clip: str | None = None, seed: int = 0,
                 speed: float = 1.0, on_frame: Callable[["StudioCore"], None] | None = None, frame_hz: float = 30.0,
                 label: str | None = None, watched: Callable[[], bool] | None = None,
                 shape: dict[str, float] | None = None):
        self.seed = seed
        self.speed = float(speed)
        self.session = LiveSession(checkpoint, agent=agent, clip=clip, shape=shape, seed=seed, command="studio")
        self.checkpoint = checkpoint
        self.label = label or str(checkpoint)
        """The checkpoint as the user named it (typed, or picked in the page), not its run's name."""
        self.watched = watched
        """None: always step; else step only while it returns True (a viewer is connected)."""
        self.idle = False
        """The loop is not stepping because nobody watches."""
        self.generation = 0
        self.scheduler: Any = None
        self.scheduler_name = "dataset"
        self.paused = False
        self.errors = 0
        self.commands_done = 0
        self.message = f"loaded {self.label}"
        self.message_is_error = False
        self.loading: str | None = None
        self.loop_steps = 0
        """Control steps taken by the loop over all sessions (the session's own counter restarts)."""
        self.on_frame = on_frame
        """Called on the loop thread at most `frame_hz` times a second, and after every command,
        to push the pose to the 3-D view; its exceptions are reported like a failed command's."""
        self.frame_hz = frame_hz
        self._queue: collections.deque[Command] = collections.deque()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._loader: threading.Thread | None = None
        self._history: collections.deque = collections.deque(maxlen=self._history_len())
        self._frame_due = True

    # ---- the loop ----

    def start(self) -> "StudioCore":
        self._thread = threading.Thread(target=self._run, name="studio-loop", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if self._loader is not None:
            self._loader.join(timeout)
        self._close_scheduler()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _run(self) -> None:
        next_t = time.perf_counter()
        last_frame = 0.0
        while not self._stop.is_set():
            changed = self._apply_commands()
            if self.watched is not None and not self._is_watched():
                self.idle = True
                self._stop.wait(IDLE_WAIT_S)
                next_t = time.perf_counter()
                continue
            if self.idle:
                self.idle, self._frame_due = False, True
            if not self.paused:
                self._step()
                changed = True
            now = time.perf_counter()
            if self.on_frame is not None and (changed or self._frame_due) and \
                    (now - last_frame >= 1.0 / self.frame_hz or self._frame_due):
                last_frame = now
                self._frame_due = False
                try:
                    self.on_frame(self)
                except Exception as exc:  # noqa: BLE001 - the view must never stop the simulation
                    self._fail("3-D view", exc)
            next_t += self.session.env.dt / self.speed
            now = time.perf_counter()
            if next_t < now - MAX_LAG_S:
                next_t = now
            self._stop.wait(max(0.0, next_t - now) if not self.paused else 1.0 / self.frame_hz)

    def _is_watched(self) -> bool:
        try:
            return bool(self.watched())
        except Exception:  # noqa: BLE001 - a failing check must not stop the loop: step as if watched
            return True

    def _step(self) -> None:
        s = self.session
        try:
            info = s.step()
        except Exception as exc:  # noqa: BLE001 - report, reset, go on
            self._fail("step", exc)
            try:
                s.reset()
            except Exception as exc2:  # noqa: BLE001
                self._fail("reset after a failed step", exc2)
                self.paused = True
            return
        self.loop_steps += 1
        with self._lock:
            self._history.append((s.steps * s.env.dt, info["reward"], dict(info.get("terms") or {})))

    def _apply_commands(self) -> bool:
        with self._lock:
            batch = list(self._queue)
            self._queue.clear()
        if not batch:
            return False
        merged: list[Command] = []
        for c in batch:  # consecutive shape commands (a dragged slider) become one morph
            if c.shape is not None and merged and merged[-1].shape is not None:
                merged[-1].shape.update(c.shape)
            else:
                merged.append(Command(c.label, c.apply, dict(c.shape) if c.shape is not None else None, c.quiet))
        for c in merged:
            try:
                msg = self._apply_shape(c.shape) if c.shape is not None else c.apply()
            except Exception as exc:  # noqa: BLE001 - a bad value must never stop the loop
                self._fail(c.label, exc)
                continue
            if c.quiet:
                continue
            self.commands_done += 1
            if msg:
                self._say(msg)
        self._frame_due = True
        return True

    def _say(self, text: str) -> None:
        self.message, self.message_is_error = text, False

    def _fail(self, label: str, exc: BaseException) -> None:
        text = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
        self.message, self.message_is_error = f"{label}: {text}", True
        self.errors += 1  # NOTE: after the message: a reader that sees the count sees its message
        if not isinstance(exc, ValueError):
            traceback.print_exc()

    def submit(self, label: str, apply: Callable[[], str | None], shape: dict[str, float] | None = None) -> None:
        """Queue `apply` for the loop thread (any thread may call this)."""
        with self._lock:
            self._queue.append(Command(label, apply, shape))

    def query(self, fn: Callable[[LiveSession], Any], timeout: float = 5.0) -> Any:
        """`fn(session)` run on the loop thread between two steps (a consistent read, e.g. the
        body's height); waits for the result. Not a user command: not counted, no message."""
        future: concurrent.futures.Future = concurrent.futures.Future()

        def apply() -> None:
            try:
                future.set_result(fn(self.session))
            except Exception as exc:  # noqa: BLE001 - handed to the caller
                future.set_exception(exc)
        with self._lock:
            self._queue.append(Command("query", apply, quiet=True))
        return future.result(timeout)

    # ---- commands: what the page's controls call ----

    def set_shape(self, values: dict[str, float]) -> None:
        """Morph to the current shape with `values` set (merged with other pending morphs)."""
        self.submit("shape", lambda: None, shape={str(k): v for k, v in values.items()})

    def set_shape_text(self, text: str) -> None:
        """NAME=VALUE pairs typed by the user; a parse error is counted like a bad value."""
        def apply() -> str:
            return self._apply_shape(parse_shape_text(text))
        self.submit("shape", apply)

    def _apply_shape(self, values: dict[str, float]) -> str:
        s = self.session
        if not s.shape_can_change:
            raise ValueError(f"{s.loaded.name}'s body cannot change shape ({SHAPE_FIXED.get(s.kind, 'it trained on one body')})")
        good: dict[str, float] = {}
        bad: list[str] = []
        for name, value in values.items():  # NOTE: one bad value must not drop the good ones
            try:
                s.shape_vector({name: value})
                good[name] = value
            except ValueError as exc:
                bad.append(str(exc))
        if good:
            s.set_shape(good)
        if bad:
            raise ValueError("; ".join(bad))
        return "morphed " + ", ".join(f"{k}={v:.3g}" for k, v in good.items()) + f" (height {s.body_height_m():.2f} m)"

    def set_agent(self, agent: str) -> None:
        def apply() -> str:
            if agent not in AGENTS:
                raise ValueError(f"agent {agent!r} is not one of {', '.join(AGENTS)}")
            self.session.agent = agent
            return f"agent: {agent}"
        self.submit("agent", apply)

    def set_clip(self, clip: str) -> None:
        """The executor follows `clip` from now; a shape controller reloads with it."""
        def apply() -> str | None:
            s = self.session
            if clip not in s.clips:
                raise ValueError(f"clip {clip!r} cannot play with this checkpoint; choose from: {', '.join(s.clips)}")
            if s.kind == "executor":
                s.clip = clip
                s.reset(restart=True)  # the clip from its start, not the running schedule resumed
                return f"clip: {clip}"
            if clip == s.clip or (s.clip is None and len(s.clips) == 1):
                return None
            self.load(self.checkpoint, clip=clip)
            return None
        self.submit("clip", apply)

    def use_scheduler(self, name: str) -> None:
        self.submit("scheduler", lambda: self._use_scheduler(name))

    def _use_scheduler(self, name: str, **options: Any) -> str:
        s = self.session
        if name not in SCHEDULERS:
            raise ValueError(f"scheduler {name!r} is not one of {', '.join(SCHEDULERS)}")
        if s.kind != "executor":
            raise ValueError(f"schedulers drive the executor; {self.label} is "
                             + ("a shape controller that follows its own clip" if s.kind == "shape" else f"a {s.kind} task"))
        try:
            # lazy: optional: if the schedulers fail to load, the studio reports it (except below)
            from common.tasks.executor.schedulers.factory import make_scheduler
        except ImportError as exc:
            raise ValueError(f"the schedulers are not available in this checkout (common.tasks.executor.schedulers.factory: {exc})") from None
        if name == "video":
            options = {"host": "127.0.0.1", "port": 0, **options}
        scheduler = make_scheduler(name, s.env, **options)
        s.use_scheduler(scheduler)
        self._close_scheduler()
        self.scheduler, self.scheduler_name = scheduler, name
        port = getattr(scheduler, "port", None)
        return f"scheduler: {name}" + (f" (listening on udp://127.0.0.1:{port})" if name == "video" and port else "")

    def _close_scheduler(self) -> None:
        if self.scheduler is not None and hasattr(self.scheduler, "close"):
            try:
                self.scheduler.close()
            except Exception:  # noqa: BLE001
                traceback.print_exc()
        self.scheduler = None

    def steer(self, key: str) -> None:
        """A keyboard-scheduler command (left, right, faster, slower, stop, style:<name>);
        switches to the keyboard scheduler first when another one runs."""
        def apply() -> str:
            if key not in KEYS and not (key.startswith("style:") and len(key) > 6):
                raise ValueError(f"key {key!r} is not one of {', '.join(KEYS)} or style:<name>")
            if self.scheduler_name != "keyboard" or self.scheduler is None:
                self._use_scheduler("keyboard")
            self.scheduler.command(key)
            return f"keyboard: {key}"
        self.submit("steer", apply)

    def queue_clip(self, clip: str) -> None:
        """Stitch `clip` after the queued ones (switches to the stitch scheduler first)."""
        def apply() -> str:
            s = self.session
            if clip not in s.clips:
                raise ValueError(f"clip {clip!r} is unknown; choose from: {', '.join(s.clips)}")
            if s.kind != "executor":
                raise ValueError(f"clip queues (stitching) drive the executor; {self.label} is a {s.kind} task")
            if self.scheduler_name != "stitch" or self.scheduler is None:
                self._use_scheduler("stitch", clips=(clip,))
                return f"stitch: started with {clip}"
            self.scheduler.enqueue(clip)
            return f"stitch: queued {clip}"
        self.submit("queue", apply)

    def throw(self, speed_mps: float = 10.0) -> None:
        def apply() -> str:
            self.session.throw_projectile(speed_mps)
            return f"threw a projectile at {float(speed_mps):g} m/s" if self.session.kind == "executor" \
                else f"pushed (the momentum of a 2 kg ball at {float(speed_mps):g} m/s)"
        self.submit("projectile", apply)

    def set_mass(self, factor: float) -> None:
        def apply() -> str:
            self.session.scale_mass(factor)
            return f"mass x{float(factor):.2f}"
        self.submit("mass", apply)

    def reset(self) -> None:
        def apply() -> str:
            self.session.reset()
            return "reset"
        self.submit("reset", apply)

    def set_paused(self, paused: bool) -> None:
        def apply() -> str:
            self.paused = bool(paused)
            return "paused" if paused else "running"
        self.submit("pause", apply)

    def load(self, checkpoint: str, agent: str | None = None, clip: str | None = None, label: str | None = None) -> None:
        """Load another checkpoint (or the same with another clip) in a thread of its own; the
        loop keeps stepping the old session until the new one is swapped in. `label`: the name
        shown for it (default: the path as given; the same label when reloading with a clip)."""
        if self._loader is not None and self._loader.is_alive():
            self.submit("load", _raiser(ValueError(f"still loading {self.loading}; try again in a moment")))
            return
        agent = agent or self.session.agent
        label = label or (self.label if checkpoint == self.checkpoint else str(checkpoint))
        self.loading = label

        def work() -> None:
            try:
                new = LiveSession(checkpoint, agent=agent, clip=clip, seed=self.seed, command="studio")
            except SystemExit as exc:  # NOTE: checkpoint.load_trained refuses a bad checkpoint with SystemExit(message)
                self.loading = None
                self.submit("load", _raiser(ValueError(str(exc))))
                return
            except Exception as exc:  # noqa: BLE001
                self.loading = None
                self.submit("load", _raiser(exc))
                return

            def swap() -> str:
                self._close_scheduler()
                self.session, self.checkpoint, self.label = new, checkpoint, label
                self.scheduler_name = "dataset"
                with self._lock:
                    self._history = collections.deque(maxlen=self._history_len())
                self.generation += 1
                self.loading = None
                return f"loaded {label}" + (f" ({clip})" if clip else "")
            self.submit("load", swap)

        self._loader = threading.Thread(target=work, name="studio-load", daemon=True)
        self._loader.start()

    # ---- what the page shows ----

    def _history_len(self) -> int:
        return max(2, int(round(HISTORY_S / self.session.env.dt)))

    def snapshot(self) -> dict[str, Any]:
        """A consistent copy of what the page shows (any thread)."""
        s = self.session
        with self._lock:
            hist = list(self._history)
        names = list(hist[-1][2]) if hist else []
        t = np.array([h[0] for h in hist], float)
        terms = {n: np.array([h[2].get(n, np.nan) for h in hist], float) for n in names}
        last = s.last or {}
        tracking = s.tracking()
        lo, hi = s.shape_box
        return {
            "name": self.label, "run_name": s.loaded.name, "kind": s.kind, "idle": self.idle,
            "video": video_status(self.scheduler), "agent": s.agent, "generation": self.generation,
            "time_s": s.steps * s.env.dt, "steps": s.steps, "loop_steps": self.loop_steps, "resets": s.resets,
            "last_reset": s.last_reset, "reset_text": s.reset_text(),
            "return": s.episode_return, "reward": float(last.get("reward", 0.0)),
            "clip": tracking[0] if tracking else last.get("clip_id", s.clip), "clip_time_s": tracking[1] if tracking else None,
            "distance_m": last.get("distance_m"),
            "scheduler": self.scheduler_name, "mass_factor": s.mass_factor, "paused": self.paused,
            "errors": self.errors, "message": self.message, "message_is_error": self.message_is_error,
            "loading": self.loading, "t": t, "reward_hist": np.array([h[1] for h in hist], float), "terms": terms,
            "shape_names": s.shape_names, "shape": np.asarray(s.params[: s.n_shape], float).copy(),
            "shape_low": lo, "shape_high": hi,
        }
