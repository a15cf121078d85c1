"""A live session: one environment of a trained checkpoint stepped by one agent, that can be
steered while it runs. `morphmimic play` and the browser studio are thin clients of it.

The agent is the checkpoint's policy (mean action), or, for comparison, zero actions or
uniform random actions in [-1, 1]. What can change while it runs:

- the body (shape controllers, Won & Lee 2019 section 3 "shape change on the fly"):
  `set_shape` morphs it through `ImitateEnv.set_shape`, the state carried over; an executor
  trained over body shapes (`--task.body.vary-shape`, preset `executor-shape`) is morphed live
  too, through `ExecutorEnv.set_shape` (the state carried over, the tracked clip retargeted onto
  the new body at the same clip time) while it tracks a clip (dataset scheduler) or follows
  the keyboard; under the stitch or video scheduler a change is refused (their buffered frames
  are the old body's); `shape=` at the start builds that body for the first episode;
- the target frames (the executor, UniCon 2020 "Schedulers"): `use_scheduler` swaps the
  executor's scheduler (dataset, stitch, keyboard, video) without touching the policy;
- perturbations: `throw_projectile` (the executor's balls; a shape controller gets a push of
  the same momentum instead), `scale_mass` (heavier or lighter, UniCon Table 2);
- `reset`; a fallen shape controller, or an executor that lost its target (`LOST_M`), is
  reset by itself when `auto_reset` is on. `resets` counts the resets and `last_reset` names
  the cause of the last one (`RESET_CAUSES`).

The reach arm runs too: its episodes keep the checkpoint's length and each reset draws a new
target (the arm has no shape to change, no body to push, no clip to follow). A checkpoint whose
task does not list the session's command (`play`, `studio`) in the task registry
(`common.tasks.registry.command_refusal`) is refused with a `ValueError` naming the tasks the
command takes.

What a reset does to the executor's schedule (`ExecutorEnv.reset`): the dataset scheduler
draws anew; stitch, keyboard and video resume, the body put back on the schedule's current
target frame (the stitch queue's clip and time, the key script's clock, the video clock go on),
so a demo that loses its target once a second still reaches the later clips and keys.
`use_scheduler` and a clip chosen with `reset(restart=True)` begin the schedule from its start.

Every value a user hands in (shape values, mass factors, clip names, speeds) is checked here
and refused with a `ValueError` that names it and what is allowed; the session keeps running.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
import torch

from common.characters.character import extent
from common.characters.mass import scale_body_mass
from common.config_limits import SEED, Limit, check_limits, validated
from common.tasks.registry import command_refusal, make_env, task_clips, task_entry
from learner.checkpoint import Loaded, load_trained, make_policy
from learner.cli_options import value_list
from learner.evaluation import harness

Agent = Literal["policy", "zero", "random"]
AGENTS: tuple[str, ...] = typing.get_args(Agent)
"""Who acts: the checkpoint's policy (mean action), zero actions, or uniform random actions."""
Scheduler = Literal["dataset", "stitch", "keyboard", "video"]
SCHEDULERS: tuple[str, ...] = typing.get_args(Scheduler)
"""Where the executor's target frames come from (`common.tasks.executor.schedulers.factory`)."""
LOST_M = 0.5
"""The executor has lost its target when the mean body-position error exceeds this (PHC's
success criterion, Luo et al. 2023); the session then resets (with `auto_reset`)."""
BODY_PRESETS: tuple[tuple[str, dict[str, float]], ...] = (
    ("tall", {"global_z": 1.4}), ("short", {"global_z": 0.6}), ("wide", {"global_x": 1.4, "global_y": 1.4}),
    ("long legs", {"leg_length": 1.5}), ("short legs", {"leg_length": 0.6}), ("long arms", {"arm_length": 1.5}),
    ("bigger", {"scale": 1.4}), ("smaller", {"scale": 0.6}),
    ("tall", {"height": 1.4}), ("short", {"height": 0.8}), ("thick", {"thickness": 1.4}), ("thin", {"thickness": 0.6}),
)
"""Won & Lee 2019 Figure 1's bodies by parameter name (`learner.evaluation.shape.morph_demo.SCHEDULES`' keyframes);
a parameterization offers those whose parameters it has."""
RESET_CAUSES = {
    "lost": f"the executor lost its target (mean body error > {LOST_M} m)",
    "fell": "a shape controller fell (its task's termination)",
    "time limit": "the episode's time limit (or a stopping schedule's end)",
    "divergence": "the physics diverged",
    "user": "asked for (the studio's reset, a new clip)",
}
"""The causes `LiveSession.step` and `reset` record in `last_reset`; an executor ended by one of
its reward terms (a checkpoint's own termination rule) records the term's name."""
SHAPE_FIXED = {"executor": "this executor trained on the base humanoid only (no --task.body.vary-shape; "
                            "the executor-shape preset trains over shapes)",
               "reach": "the reach arm has no shape parameters"}
"""Why a family's body cannot change shape (a shape controller's: it trained on one body)."""
PUSH_MOMENTUM_NS = 20.0
"""A shape controller's stand-in for a projectile: the executor's 2 kg ball at 10 m/s."""


def finite_number(value: Any, what: str, allowed: str) -> float:
    """`value` as a finite float, else ValueError naming `what`, the value and what is `allowed`
    (strings, None, lists and NaN alike: nothing from a user raises a TypeError past here)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if isinstance(value, bool) or not math.isfinite(v):
        raise ValueError(f"{what} = {value!r} is not a finite number; it must be {allowed}")
    return v


def number_pair(text: str, sep: str, number_at: int) -> tuple[str, float] | None:
    """(the word, the finite number) of `text` split once at `sep`, the number at position
    `number_at` (0 or 1); None when that does not parse."""
    parts = text.split(sep, 1)
    if len(parts) != 2 or not parts[0] or not parts[1]:
        return None
    try:
        value = float(parts[number_at])
    except ValueError:
        return None
    return (parts[1 - number_at], value) if math.isfinite(value) else None


def shape_pair(text: str) -> tuple[str, float]:
    """'global_z=1.2' -> ('global_z', 1.2); ValueError naming `text` when it is not NAME=VALUE
    with a finite number (the name is checked by `LiveSession.set_shape`)."""
    pair = number_pair(text, "=", 1)
    if pair is None:
        raise ValueError(f"{text!r} is not NAME=VALUE with a finite number (e.g. global_z=1.2)")
    return pair


@validated
@dataclass(kw_only=True)
class SessionOptions:
    """The command-line options a `LiveSession` opens with (`morphmimic play`, `morphmimic studio`)."""

    agent: Agent = "policy"
    """Who acts: the policy (mean action), or zero / random actions for comparison."""
    clip: str | None = None
    """The clip to follow (the executor: any humanoid clip)."""
    seed: int = 0
    """Seed of the session's starts and random actions."""
    shape: Annotated[tuple[tuple[str, float], ...], value_list(shape_pair, "NAME=VALUE", lambda p: f"{p[0]}={p[1]:g}")] = ()
    """Shape parameters of a shape controller or of an executor trained over shapes (executor-shape),
    the body built for the first episode (morphmimic character PRESET --list names them)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"seed": SEED}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def live_task(loaded: Loaded, clip: str | None = None, episode_s: float = 3600.0):
    """The checkpoint's task as a live session runs it: long episodes; for the executor, every
    humanoid clip trackable, rescheduled at a clip's end, projectiles in the scene, no reactive
    initialization and no termination (the session reads the checkpoint's own rule off the
    reward terms and resets by itself)."""
    cfg = loaded.cfg.task
    if task_entry(cfg.name).family == "reach":  # its own episode length: each episode a new target
        return cfg
    if cfg.name == "executor":
        ex = dataclasses.replace(cfg.executor, clips=(clip,) if clip else (), split="all", at_clip_end="reschedule",
                                 reactive_init=False, on_frame_share=0.0, catch_up_steps=0, termination="none",
                                 projectile=True)
        return dataclasses.replace(cfg, episode_s=episode_s, executor=ex)
    return dataclasses.replace(harness.eval_task(cfg, episode_s), **({"clip_id": clip} if clip else {}))


def video_status(scheduler: Any) -> str | None:
    """The video scheduler's packets as one line: received, rejected by reason (`pose_packet.REASONS`,
    out_of_order, ik, socket), dropped by the kernel (a full receive buffer) and the last rejection's message; None for another scheduler. A
    sender of the wrong layout is seen here (`rejected 16 (joint_count 16); last: joint_count:
    packet has 16 joints, this receiver expects 15`) instead of a character standing still."""
    if scheduler is None or not hasattr(scheduler, "rejected") or not hasattr(scheduler, "received"):
        return None
    rejected = dict(scheduler.rejected)
    text = f"video udp:{getattr(scheduler, 'port', '?')}: received {scheduler.received}, rejected {sum(rejected.values())}"
    if rejected:
        text += " (" + ", ".join(f"{k} {v}" for k, v in sorted(rejected.items(), key=lambda kv: -kv[1])) + ")"
    if hasattr(scheduler, "dropped"):  # datagrams the kernel dropped before they could be read (a full buffer)
        text += f", dropped by the kernel {scheduler.dropped()}"
    if rejected and getattr(scheduler, "last_error", ""):
        text += f"; last: {scheduler.last_error}"
    return text


class LiveSession:
    """One environment of `checkpoint` driven by `agent`; see the module docstring."""

    def __init__(self, checkpoint: str, agent: str = "policy", clip: str | None = None,
                 shape: dict[str, float] | None = None, seed: int = 0, auto_reset: bool = True,
                 command: str = "play"):
        if agent not in AGENTS:
            raise ValueError(f"agent {agent!r} is not one of {', '.join(AGENTS)}")
        self.loaded = load_trained(checkpoint)
        refusal = command_refusal(self.loaded.cfg.task.name, command)
        if refusal is not None:
            raise ValueError(refusal)
        self.kind = task_entry(self.loaded.cfg.task.name).family
        """The task's family: "shape", "executor" or "reach"."""
        self.clips = [c for c, _ in task_clips(live_task(self.loaded))]
        """The clips this checkpoint can follow: every humanoid clip (the executor) or its own task's."""
        if clip and clip not in self.clips:
            raise ValueError(f"clip {clip!r} cannot play with this checkpoint; choose from: {', '.join(self.clips)}")
        self.env = make_env(live_task(self.loaded, clip), seed=seed)
        self.policy = make_policy(self.loaded, self.env.obs_dim, self.env.act_dim)
        self.agent, self.auto_reset = agent, auto_reset
        self.rng = np.random.default_rng(seed)
        self.seed = seed
        self.clip = clip
        self.mass_factor = 1.0
        self.steps = self.resets = 0
        self.last_reset: str | None = None
        self._tracking: tuple[str, float] | None = None
        """The cause of the last reset (`RESET_CAUSES`, or a reward term's name); None before any."""
        self.episode_return = 0.0
        self.last: dict[str, Any] = {}
        self.scheduler: Any = None
        """The scheduler given to `use_scheduler` (None: the task's own)."""
        self._base_masses: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.params = self.env.space.default_array.copy()
        if shape:
            if not self.shape_can_change:
                raise ValueError(f"{self.loaded.name}'s body cannot change shape "
                                 f"({SHAPE_FIXED.get(self.kind, 'it trained on one body')})")
            self.params[: self.n_shape] = self.shape_vector(shape)
        self.reset(cause=None)

    # ---- what the body is ----

    @property
    def n_shape(self) -> int:
        """How many leading entries of the parameter vector are shape (the rest: task parameters)."""
        return int(getattr(self.env, "n_shape", len(self.env.space.names)))

    @property
    def shape_names(self) -> tuple[str, ...]:
        return tuple(self.env.space.names[: self.n_shape])

    @property
    def shape_box(self) -> tuple[np.ndarray, np.ndarray]:
        s = self.env.space
        return np.asarray(s.low[: self.n_shape], float), np.asarray(s.high[: self.n_shape], float)

    @property
    def shape_can_change(self) -> bool:
        """Shape controllers morph, and so does an executor trained over body shapes; an executor
        trained on the base humanoid only has its box pinned to the base shape."""
        lo, hi = self.shape_box
        return self.kind in ("shape", "executor") and bool(np.any(hi > lo))

    def body_presets(self) -> dict[str, dict[str, float]]:
        """Named bodies of this parameterization, as shape values (name -> value): "base" and,
        where the parameterization has the parameters, Won & Lee's Figure 1 bodies (tall, short,
        wide; long or short legs, long arms; bigger, smaller), clamped to the box."""
        names, (lo, hi) = self.shape_names, self.shape_box
        base = dict(zip(names, map(float, self.env.space.default_array[: self.n_shape])))
        out = {"base": base}
        if not self.shape_can_change:
            return out
        for label, values in BODY_PRESETS:
            if all(k in names for k in values):
                out[label] = {**base, **{k: float(np.clip(v, lo[names.index(k)], hi[names.index(k)])) for k, v in values.items()}}
        return out

    def shape_vector(self, values: dict[str, float]) -> np.ndarray:
        """The current shape with `values` (name -> value) set; ValueError naming any unknown
        name or a value outside the parameterization's box."""
        names = self.shape_names
        if not names and values:
            raise ValueError(f"{self.loaded.name} has no shape parameters (a {self.kind} task)")
        lo, hi = self.shape_box
        out = np.asarray(self.params[: self.n_shape], dtype=np.float64).copy()
        if not isinstance(values, dict):
            raise ValueError(f"shape values {values!r} must be a mapping of parameter name to number")
        for name, value in values.items():
            if name not in names:
                raise ValueError(f"shape parameter {name!r} is not one of {', '.join(names)}")
            i = names.index(name)
            v = finite_number(value, f"shape parameter {name}", f"in [{lo[i]:g}, {hi[i]:g}]")
            if not lo[i] <= v <= hi[i]:
                raise ValueError(f"shape parameter {name} = {value!r} is outside [{lo[i]:g}, {hi[i]:g}]")
            out[i] = v
        return out

    def body_height_m(self) -> float:
        """The body's vertical extent now (m), from its geoms in the current pose."""
        lo, hi = extent(self.env.model, self.env.data, 2, self.character_bodies())
        return hi - lo

    def character_bodies(self) -> np.ndarray:
        """Body ids of the character (not the world, not the executor's projectiles, not a
        mocap marker such as the reach target)."""
        n = self.env.ref_model.nbody if self.kind == "executor" else self.env.model.nbody
        ids = np.arange(1, n)
        return ids[self.env.model.body_mocapid[ids] < 0]

    @property
    def root_body(self) -> int:
        return int(getattr(self.env, "root_body", 1))

    @property
    def is_swimmer(self) -> bool:
        return bool(getattr(getattr(self.env, "character", None), "is_swimmer", False))

    @property
    def view(self) -> dict[str, float]:
        """Where a camera should stand for this body when its environment says so (its
        `view_distance_m`, `view_elevation_deg`, as the reach arm's does): `distance_m`,
        `elevation_deg`; {} for the characters (the viewers' own defaults)."""
        view = {"distance_m": getattr(self.env, "view_distance_m", None),
                "elevation_deg": getattr(self.env, "view_elevation_deg", None)}
        return {k: float(v) for k, v in view.items() if v is not None}

    # ---- running ----

    def reset(self, cause: str | None = "user", restart: bool | None = None) -> None:
        """A new episode. `cause` (None: a start, not counted) is counted in `resets` and kept
        in `last_reset`. The executor's schedule is begun anew or resumed as `ExecutorEnv.reset`
        decides (the dataset scheduler draws anew on `clip`; stitch, keyboard and video resume
        on their current target frame); `restart=True` begins it from its start."""
        if cause is not None:
            self.resets += 1
            self.last_reset = cause
        clip = self.clip if self.kind == "executor" else None
        if self.kind == "reach" and cause is not None:  # a new episode, a new target
            self.params = self.env.space.uniform(self.rng, 1)[0]
        if self.kind == "executor":
            self.obs, _ = self.env.reset(self.seed + self.resets, self.params, clip_id=clip, restart=restart)
        else:
            self.obs, _ = self.env.reset(self.seed + self.resets, self.params)
        self._apply_mass()
        self.episode_return = 0.0
        self.episode_steps = 0
        self._track()

    def action(self) -> np.ndarray:
        if self.agent == "zero":
            return np.zeros(self.env.act_dim)
        if self.agent == "random":
            return self.rng.uniform(-1.0, 1.0, self.env.act_dim)
        with torch.no_grad():
            a, _ = self.policy.act(self.obs[None], deterministic=True)
        return a[0]

    def step(self) -> dict[str, Any]:
        """One control step; returns what happened: reward, its terms, whether the episode
        ended (and why) and whether the session reset."""
        obs, r, term, trunc, info = self.env.step(self.action())
        self.obs = obs
        self.steps += 1
        self.episode_steps += 1
        self.episode_return += float(r)
        terms = {k: float(v) for k, v in (info.get("terms") or {}).items()}
        ended = None
        if info.get("diverged"):
            ended = "divergence"
        elif self.kind == "executor":
            # NOTE: live, the executor is reset when it has lost the target (PHC's criterion), not
            # at the first reward term below alpha: a viewer wants to see it recover or fall
            if float(info.get("body_error_m", 0.0)) > LOST_M:
                ended = "lost"
            elif term:
                ended = str(info.get("ended_by") or "terminated")
            elif trunc:
                ended = "time limit"
        elif term:
            ended = "fell"
        elif trunc:
            ended = "time limit"
        self.last = {"step": self.steps, "reward": float(r), "terms": terms, "ended": ended,
                     "return": self.episode_return, "episode_steps": self.episode_steps, "reset": False,
                     **{k: info[k] for k in ("clip_id", "clip_time_s", "distance_m") if k in info}}
        if ended and self.auto_reset:
            self.reset(cause=ended)
            self.last["reset"] = True
        else:
            self._track()
        return self.last

    # ---- steering ----

    def set_shape(self, values: dict[str, float]) -> np.ndarray:
        """Morph the body to the current shape with `values` set, keeping its state (shape
        controllers, and an executor trained over shapes: `ExecutorEnv.set_shape`, live under the
        dataset and keyboard schedulers, refused under stitch and video); returns the new shape
        vector. Nothing changes when a value is refused."""
        if not self.shape_can_change:
            why = SHAPE_FIXED.get(self.kind, "it trained on one body")
            raise ValueError(f"this checkpoint's body cannot change shape ({why})")
        shape = self.shape_vector(values)
        self.env.set_shape(shape)
        self.params = np.concatenate([shape, np.asarray(self.params[self.n_shape :], float)])
        self._apply_mass()
        self.obs = self.env.observe_now() if self.kind == "executor" else self.env._obs_safe()
        return shape

    def use_scheduler(self, scheduler) -> None:
        """Drive the executor with another scheduler (UniCon's run-time schedulers) from now:
        a new episode that begins it (not counted as a reset)."""
        if self.kind != "executor":
            raise ValueError("schedulers drive the executor; a shape controller follows its own clip")
        self.env.use_scheduler(scheduler)
        self.scheduler = scheduler
        self.reset(cause=None)

    def throw_projectile(self, speed_mps: float = 10.0) -> None:
        """The executor: a 2 kg ball at `speed_mps`; a shape controller: a sideways push of the
        same momentum on its root."""
        speed_mps = finite_number(speed_mps, "projectile speed (m/s)", "in (0, 100]")
        if not 0.0 < speed_mps <= 100.0:
            raise ValueError(f"projectile speed {speed_mps} m/s must be in (0, 100]")
        if self.kind == "executor":
            self.env.throw_projectile(float(speed_mps), 2.0, self.rng)
            return
        if self.kind != "shape":
            raise ValueError(f"projectiles and pushes are for the characters (shape controllers, the executor); "
                             f"{self.loaded.name} is a {self.kind} task")
        a = self.rng.uniform(0.0, 2.0 * math.pi)
        mass = float(np.sum(self.env.model.body_mass[self.character_bodies()]))
        dv = PUSH_MOMENTUM_NS * float(speed_mps) / 10.0 / mass
        self.env.data.qvel[0:2] += dv * np.array([math.cos(a), math.sin(a)])

    def scale_mass(self, factor: float) -> None:
        """Every body `factor` times heavier than the checkpoint's (0.25 .. 4)."""
        factor = finite_number(factor, "mass factor", "in [0.25, 4]")
        if not 0.25 <= factor <= 4.0:
            raise ValueError(f"mass factor {factor!r} must be in [0.25, 4]")
        self.mass_factor = factor
        self._apply_mass()

    def _apply_mass(self) -> None:
        if self.kind == "executor":
            self.env.scale_mass(self.mass_factor)
            return
        m = self.env.model  # NOTE: a morph or a reset may hand out another model: keep each one's own masses
        base = self._base_masses.setdefault(id(m), (m.body_mass.copy(), m.body_inertia.copy()))
        scale_body_mass(m, base[0], base[1], self.mass_factor)

    def tracking(self) -> tuple[str, float] | None:
        """(clip id, seconds into it) the executor's scheduler tracked after the last step or
        reset (its `status()`'s clip_id and clip_time_s; a live source: "video" and its clock);
        None for a shape controller. Read on the stepping thread, so other threads (the
        studio's page) may read this without touching the scheduler."""
        return self._tracking

    def _track(self) -> None:
        if self.kind == "executor":
            st = self.env.scheduler.status()
            self._tracking = (str(st.get("clip_id", "")), float(st.get("clip_time_s", 0.0)))

    def reset_text(self) -> str:
        """'resets N' and, after one, the last one's cause: 'resets 3 (last: lost)'."""
        return f"resets {self.resets}" + (f" (last: {self.last_reset})" if self.last_reset else "")

    def status(self) -> dict[str, Any]:
        """What the studio shows beside the character."""
        return {"kind": self.kind, "agent": self.agent, "checkpoint": str(self.loaded.path), "name": self.loaded.name,
                "steps": self.steps, "resets": self.resets, "last_reset": self.last_reset, "mass_factor": self.mass_factor,
                "shape": dict(zip(self.shape_names, map(float, self.params[: self.n_shape]))),
                "height_m": self.body_height_m(), **self.last}

