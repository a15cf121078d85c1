"""`ImitateEnv`: Won & Lee 2019's environment (METHOD.md A) over one character family.

Each episode builds the character `C = F(B, b)` from the shape `b` the sampler drew, retargets
the task's reference clip onto it (`references.play`) and starts at a random phase of the clip
in the reference state (no per-episode standing-pose solve: the retargeted reference already
has the feet on the floor). Every control step (30 Hz, `TaskConfig.control_hz`) the action `a`
`[nu]` is a deviation from the reference pose: the PD target is `q_ref(t + dt) + action_scale a`
(rotation vectors on ball joints), tracked by MuJoCo's implicit PD (stable PD, builder.py).

State (METHOD.md A, `s = (s_b, s_d, s_s)`), all in the heading frame of the root (yaw and
planar position left out): s_b the episode parameters (shape, then task parameters); s_d root
height, orientation and velocities, joint vector `[nu]`, joint velocities `[nu]`, end effectors
relative to the root `[3E]`; s_s reference joint vector, root height and orientation at t,
t + 0.5 s, t + 1.0 s, the target velocity `[2]`, the 2-s average and current COM velocity,
and the clip phase (sin, cos).

Reward: `rewards.py` (weights and sensitivities from METHOD.md A, reward normalization
switchable: `TaskConfig.reward_normalization`). Termination: a fall (a floor contact of any
body but the feet, or for swimmers a root further than `max_root_deviation` body lengths off
the reference's course, sideways or vertically) and simulator divergence (`base.diverged_step`)
terminate; the horizon (`episode_s`, 30 s) truncates.
"""

from __future__ import annotations

import collections
import dataclasses
import math

import mujoco
import numpy as np

from common.characters import CharacterFactory, base_character, morph
from common.characters.morph import lift_out_of_floor
from common.characters.operator import gains_follow_torque_limits
from common.lru import Lru
from common.params import ParamSpace
from common.tasks.base import TaskConfig, diverged_step, step_physics
from common.tasks.content_bounds import OBS_MAX_ABS_LIMIT, ContentBounds
from common.tasks.observations import JointLayout, heading, quat_to_mat, root_frame_features, yaw_matrix
from common.tasks.shape import references, rewards
from common.tasks.shape.stroke_model import StrokeModel
from common.tasks.shape.stroke_speed import SWIMMERS
from common.tasks.shape_params import shape_param_space

LOOKAHEAD_S = (0.0, 0.5, 1.0)
"""Reference postures in the state: now, 0.5 s and 1.0 s ahead (METHOD.md A)."""
REF_CHUNK_STEPS = 96
"""Control steps of reference sampled at a time (about 3 s; episodes often end sooner early on)."""
COM_WINDOW_S = 2.0
"""v_com in R_task is the COM velocity averaged over the last 2 s (METHOD.md A)."""
TASK_PARAMS = {
    "speed": ("speed", "playback speed factor of the reference; target velocity scales with it"),
    "heading": ("heading", "walking direction (rad, world yaw) the reference is rotated to"),
}


def character_preset(cfg: TaskConfig) -> str:
    """The character preset of a shape task: `cfg.body.character`, else the task name."""
    preset = cfg.body.character or cfg.name
    if preset not in references.DEFAULT_CLIPS:
        raise ValueError(f"task {cfg.name!r}: character {preset!r} has no shape task; choose one of {sorted(references.DEFAULT_CLIPS)}")
    return preset


class ImitateEnv:
    """Gymnasium-style environment; see `common.tasks.base.Env` and the module docstring."""

    @staticmethod
    def param_space(cfg: TaskConfig) -> ParamSpace:
        """Shape parameters of `cfg.body.parameterization` (collapsed to the base shape when
        `cfg.body.vary_shape` is off), then the task parameters of `cfg.imitate.task_params`."""
        shape = shape_param_space(character_preset(cfg), cfg.body, 1.0 / cfg.sim_hz)
        names, low, high, doc = list(shape.names), list(shape.low), list(shape.high), list(shape.doc)
        ranges = {"speed": cfg.imitate.speed_range, "heading": cfg.imitate.heading_range_rad}
        for name in cfg.imitate.task_params:
            if name not in TASK_PARAMS:
                raise ValueError(f"task parameter {name!r} is not one of {sorted(TASK_PARAMS)}")
            names.append(name)
            low.append(float(ranges[name][0]))
            high.append(float(ranges[name][1]))
            doc.append(TASK_PARAMS[name][1])
        default = list(shape.default) + [1.0 if n == "speed" else 0.0 for n in cfg.imitate.task_params]
        default = [min(max(d, lo), hi) for d, lo, hi in zip(default, low, high)]
        return ParamSpace(tuple(names), tuple(low), tuple(high), tuple(default), tuple(doc))

    @staticmethod
    def check(cfg: TaskConfig):
        """A swimmer's stroke-speed model loads and fits the shape parameters when the task asks
        for it (`stroke_model_for`), and only a swimmer observes its course;
        ValueError otherwise. Returns the model (None when the task uses none)."""
        preset = character_preset(cfg)
        if cfg.imitate.observe_course and not base_character(preset, 1.0 / cfg.sim_hz).is_swimmer:
            raise ValueError(f"--task.imitate.observe-course: {preset!r} is not a swimmer; only a swimmer has a "
                             "course to keep (the walkers' fall is a floor contact)")
        return stroke_model_for(cfg)

    @staticmethod
    def clips(cfg: TaskConfig) -> list[tuple[str, str]]:
        preset = character_preset(cfg)
        clip_id = cfg.imitate.clip_id or references.DEFAULT_CLIPS[preset]
        return [(clip_id, "root/locomotion")]

    @staticmethod
    def content_bounds(cfg: TaskConfig) -> ContentBounds:
        """R = sum of w_k bells in (0, 1] with w_k >= 0 (`rewards.reward_terms`): in [0, sum w]."""
        weights = tuple(cfg.imitate.reward_weights) or rewards.WEIGHTS[character_preset(cfg)]
        return ContentBounds(reward_min=0.0, reward_max=float(sum(weights)), obs_max_abs=OBS_MAX_ABS_LIMIT,
                             episode_steps=cfg.episode_steps)

    def __init__(self, cfg: TaskConfig, seed: int = 0):
        self.cfg = cfg
        self.preset = character_preset(cfg)
        self.clip_id = cfg.imitate.clip_id or references.DEFAULT_CLIPS[self.preset]
        self.timestep_s = 1.0 / cfg.sim_hz
        self.retarget = cfg.imitate.retarget_for_task()
        self.space = self.param_space(cfg)
        self.n_shape = len(self.space.names) - len(cfg.imitate.task_params)
        self.rng = np.random.default_rng(seed)
        self.base = base_character(self.preset, self.timestep_s)
        self.weights = tuple(cfg.imitate.reward_weights) or rewards.WEIGHTS[self.preset]
        self.sigmas = tuple(cfg.imitate.reward_sensitivities)
        base_clip, _ = references.task_clip(self.preset, self.clip_id, self.timestep_s)
        self.v0 = references.cycle_velocity(base_clip)
        self.tau_scale = self.base.model.actuator_forcerange[:, 1].copy()
        self._base_legs = self._legs(self.base)
        self.stroke_model = self.check(cfg)
        """The swimmer's fitted stroke-speed model under `swimmer_speed = "stroke_fit"`, else None."""
        self._cache: Lru[tuple] = Lru(max(1, cfg.imitate.character_cache))
        self._factory = CharacterFactory(self.preset, cfg.body.parameterization, timestep_s=self.timestep_s)
        self.dt = 1.0 / cfg.control_hz
        self._look = [int(round(x * cfg.control_hz)) for x in LOOKAHEAD_S]
        self._load(self.space.default_array)
        self.obs_dim = int(self._reset_state(0.0).shape[0])
        self.act_dim = int(self.model.nu)

    def _legs(self, ch) -> np.ndarray:
        """Leg lengths [n] m for the normalization; a swimmer's body length stands in."""
        return ch.leg_lengths_m if len(ch.base.legs) else np.array([ch.length_m])

    def _normalization(self, ch, shape: np.ndarray) -> rewards.Normalization:
        """Won & Lee's reward normalization for this body, with a swimmer's fitted stroke speed
        under `swimmer_speed = "stroke_fit"` (`learner.tools.stroke_fit`)."""
        norm = rewards.Normalization.from_legs(self._legs(ch), self._base_legs, ch.mass_kg, self.base.mass_kg)
        if self.stroke_model is not None:
            norm = dataclasses.replace(norm, speed_factor=self.stroke_model.ratio(shape))
        return norm

    def _load(self, params: np.ndarray) -> None:
        """Build (or fetch from the per-env cache) the character and reference for a shape."""
        shape = np.asarray(params[: self.n_shape], dtype=np.float64)

        def build() -> tuple:
            ch = self._factory.make(shape)
            self._gains(ch)
            motion = references.play(ch, self.clip_id, self.timestep_s, self.retarget)
            return ch, motion, self._normalization(ch, shape)

        self._set_character(*self._cache.get(shape.tobytes(), build))

    def _gains(self, ch) -> None:
        if self.cfg.imitate.pd_gains_follow_torque:
            gains_follow_torque_limits(ch.model, self.base.model)

    def _set_character(self, ch, motion, norm) -> None:
        self.character, self.motion, self.norm = ch, motion, norm
        self.model = ch.model
        self.layout = JointLayout(self.model)
        self.root_body = self.model.body(ch.root_body).id
        self.ee_ids = np.array([self.model.body(b).id for b in ch.end_effector_bodies], dtype=np.int64)
        foot = {int(self.model.geom(g).bodyid[0]) for g in ch.foot_geoms}
        if not self.cfg.imitate.shin_contact_is_fall:
            foot |= {int(self.model.body_parentid[b]) for b in foot}
        allowed = [b for b in range(self.model.nbody) if any(self._descends(b, f) for f in foot)]
        self.allowed_contact = np.zeros(self.model.nbody, bool)
        self.allowed_contact[allowed] = True
        self.allowed_contact[0] = True
        feet = {int(self.model.geom(g).bodyid[0]) for g in ch.foot_geoms}
        self.feet_contact = np.zeros(self.model.nbody, bool)
        """Won & Lee's fall rule: a floor contact of any body but the feet (and what hangs below
        them) is a fall, whatever `shin_contact_is_fall` says (`paper_fell`)."""
        self.feet_contact[[b for b in range(self.model.nbody) if any(self._descends(b, f) for f in feet)]] = True
        self.feet_contact[0] = True
        self.rules_differ = not self.cfg.imitate.shin_contact_is_fall and not ch.is_swimmer
        """Only then can the paper's fall come before the task's: the contact loop is run twice
        only for such a body."""
        self.length_m = float(ch.length_m) if ch.is_swimmer else 0.0

    def _descends(self, b: int, ancestor: int) -> bool:
        while b > 0:
            if b == ancestor:
                return True
            b = int(self.model.body_parentid[b])
        return False

    # ---- the reference, rotated to the episode's heading and played at its speed ----

    def _ref_qpos(self, t_s: np.ndarray) -> np.ndarray:
        """Reference qpos `[N, nq]` at episode times t_s (s), heading and speed applied."""
        q = self.motion.qpos(self.tau0 + self.speed * np.asarray(t_s, dtype=np.float64))
        q = np.atleast_2d(q).copy()
        q[:, 0:3] = q[:, 0:3] @ self.rot.T + self.ref_offset
        for row in q:
            out = np.zeros(4)
            mujoco.mju_mulQuat(out, self.rot_quat, row[3:7])
            row[3:7] = out
        return q

    def _grid(self, k: int) -> int:
        """Row of control step k in the episode's reference table (`references.GridReference`:
        the reference sampled once per control step on the grid t = k dt, with what the state
        and the reward read from it), extending the table as needed."""
        row = k + 1  # row 0 is step -1, for the centred velocity at step 0
        self.ref.ensure(row + self._look[-1] + 2)
        return row

    def _clear_table(self) -> None:
        """A new reference table for the episode's reference (motion, heading, speed, offset)."""
        self.ref = references.GridReference(self._ref_qpos, self.motion, self.model, self.layout, self.ee_ids, self.dt,
                                            REF_CHUNK_STEPS)

    def _ref_qvel(self, k: int) -> np.ndarray:
        """Reference qvel `[nv]` at step k: centred difference of the table over 2 dt."""
        return self.ref.column("qvel")[self._grid(k)]

    # ---- the Env contract ----

    def reset(self, seed: int | None, params: np.ndarray, clip_id: str | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        if clip_id not in (None, "", self.clip_id):
            raise ValueError(f"clip {clip_id!r} is not this task's clip {self.clip_id!r}")
        params = self.space.validate(params)
        self._load(params)
        phase = float(self.rng.uniform(0.0, self.motion.duration_s)) if self.cfg.imitate.random_start_phase else 0.0
        return self._reset_state(phase, params), {}

    def _reset_state(self, phase_s: float, params: np.ndarray | None = None) -> np.ndarray:
        params = self.space.default_array if params is None else params
        self.params = params.astype(np.float64)
        task = dict(zip(self.cfg.imitate.task_params, params[self.n_shape :]))
        self.speed = float(task.get("speed", 1.0))
        yaw = float(task.get("heading", 0.0))
        self.rot = yaw_matrix(yaw)
        self.rot_quat = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
        self.ref_offset = np.zeros(3)
        self.tau0 = phase_s
        self.k = 0
        self.data = mujoco.MjData(self.model)
        self._clear_table()
        row = self._grid(0)
        self.data.qpos[:] = self.ref.column("q")[row]
        self.data.qvel[:] = self._ref_qvel(0)
        if not self.character.is_swimmer:
            lift_out_of_floor(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)
        self.com_hist: collections.deque = collections.deque(maxlen=int(round(COM_WINDOW_S * self.cfg.control_hz)) + 1)
        self.com_hist.append(self.data.subtree_com[self.root_body].copy())
        self._refresh_reference()
        return self._obs()

    def _refresh_reference(self) -> None:
        row = self._grid(self.k)
        self.ref_rows = [row, row + 1, *(row + n for n in self._look[1:])]
        """Table rows of the reference now, one step ahead (the PD target) and at the lookaheads."""
        self.ref_q = self.ref.column("q")[self.ref_rows]
        self.ref_joints = self.ref.column("j")[self.ref_rows]

    def target_velocity(self) -> np.ndarray:
        """v_target `[2]` m/s in the world: the clip's cycle velocity, scaled by speed, by the
        leg-length rule (times a swimmer's fitted stroke speed under `swimmer_speed = "stroke_fit"`)
        with normalization on (rewards.Normalization.target_speed)."""
        v = self.rot[:2, :2] @ self.v0 * self.speed
        return v * (self.norm.target_speed(1.0) if self.cfg.imitate.reward_normalization else 1.0)

    def _body_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(heading frame `[3, 3]` of the root, end effectors relative to the root in it `[E, 3]`)
        of the current state; the state and the reward both use them, so `step` computes them once."""
        d = self.data
        frame = yaw_matrix(heading(quat_to_mat(d.qpos[3:7])))
        return frame, (d.xpos[self.ee_ids] - d.qpos[0:3]) @ frame

    def com_velocity_avg(self) -> np.ndarray:
        """The centre of mass's horizontal velocity `[2]` m/s in the world, averaged over the last
        `COM_WINDOW_S` (Won & Lee's v_com of the task reward)."""
        n = len(self.com_hist) - 1
        if n == 0:
            # NOTE: only right after a reset, where `_obs` has just run mj_subtreeVel.
            return self.data.subtree_linvel[self.root_body][:2].copy()
        return (self.com_hist[-1][:2] - self.com_hist[0][:2]) / (n * self.dt)

    def _obs(self, body_frame: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        d = self.data
        frame, ee = body_frame or self._body_frame()
        # NOTE: mj_step does not fill subtree_linvel (only sensors that need it do); without this
        # call the current COM velocity read zero on every step.
        mujoco.mj_subtreeVel(self.model, d)
        refs = []
        rmat = self.ref.column("rmat")
        for row, qref in zip((0, 2, 3), (self.ref_q[0], self.ref_q[2], self.ref_q[3])):
            rot = frame.T @ rmat[self.ref_rows[row]].reshape(3, 3)
            refs.append(np.concatenate([self.ref_joints[row], [qref[2]], rot[:, 0], rot[:, 1]]))
        v_target = frame[:2, :2].T @ self.target_velocity()
        v_avg = frame[:2, :2].T @ self.com_velocity_avg()
        com_vel = frame.T @ d.subtree_linvel[self.root_body]
        phase = 2.0 * math.pi * ((self.tau0 + self.speed * self.k * self.dt) / self.motion.duration_s)
        course = [frame.T @ self.course_offset() / self.length_m] if self.cfg.imitate.observe_course else []
        return np.concatenate([
            self.params, root_frame_features(d.qpos, d.qvel, frame), self.layout.to_vector(d.qpos), d.qvel[6:],
            ee.reshape(-1), *refs, v_target, v_avg, com_vel, [math.sin(phase), math.cos(phase)], *course,
        ]).astype(np.float32)

    def reward_terms(self, body_frame: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, float]:
        """The six weighted terms at the current state against the reference at the same time."""
        d, qref, row = self.data, self.ref_q[0], self.ref_rows[0]
        balls = np.concatenate([[d.qpos[3:7]], d.qpos[self.layout.ball_qpos]])
        balls_ref = np.concatenate([[qref[3:7]], qref[self.layout.ball_qpos]])
        frame, ee = body_frame or self._body_frame()
        norm = self.norm if self.cfg.imitate.reward_normalization else None
        facing = frame[:2, 0]
        facing_ref = self.ref.column("facing")[row]
        errors = {
            "pose": rewards.pose_error(balls, balls_ref, d.qpos[self.layout.hinge_qpos], qref[self.layout.hinge_qpos]),
            "velocity": rewards.mean_sq(d.qvel[6:] - self.ref.column("qvel")[row][6:]),
            "end_effector": rewards.end_effector_error(ee, self.ref.column("ee")[row].reshape(-1, 3)),
            "com_velocity": rewards.mean_sq(self.com_velocity_avg() - self.target_velocity()),
            "direction": rewards.direction_error(facing, facing_ref, norm),
            "torque": rewards.torque_error(d.actuator_force, self.tau_scale, norm),
        }
        return rewards.reward_terms(self.weights, self.sigmas, errors)

    def fell(self) -> bool:
        """A floor contact of a body other than the feet (and shins, see
        `TaskConfig.shin_contact_is_fall`) for walkers, or a swimmer's root further
        than `max_root_deviation` body lengths off its reference's course (`off_course_m`)."""
        d = self.data
        if self.character.is_swimmer:
            if self.cfg.imitate.max_root_deviation <= 0:
                return False
            return self.off_course_m() > self.cfg.imitate.max_root_deviation * self.length_m
        for i in range(d.ncon):
            c = d.contact[i]
            b1, b2 = self.model.geom_bodyid[c.geom1], self.model.geom_bodyid[c.geom2]
            if not (self.allowed_contact[b1] and self.allowed_contact[b2]):
                return True
        return False

    def off_course_m(self) -> float:
        """A swimmer's distance (m) from its reference's course: the root's offset from the
        reference root with the part along the direction of travel removed (sideways and
        vertical). Lagging behind or running ahead is left to the task term and the speed error:
        a body's stroke may be slower or faster than the speed its reference is scaled to (on
        random fish shapes, 0.78-1.18 times it with the stroke tracked closely, 10 shapes; manta
        0.27-2.56, 200 shapes: `learner.tools.stroke_fit`), and that must not end the episode as
        a fall. The reference's root moves at the length-scaled speed even when the target speed
        is the fitted one (`swimmer_speed = "stroke_fit"`): only its course counts here, and no
        reward term compares root positions."""
        return float(np.linalg.norm(self.course_offset()))

    def course_offset(self) -> np.ndarray:
        """`[3]` m in the world: the root's offset from the reference root with the part along the
        reference's direction of travel removed (`off_course_m` is its length; with
        `observe_course` the policy sees it in its heading frame, in body lengths)."""
        offset = self.data.qpos[0:3] - self.ref_q[0][0:3]
        along = self.course_direction()
        return offset - (offset @ along) * along

    def course_direction(self) -> np.ndarray:
        """`[3]` unit horizontal direction of the reference's travel in the world this episode."""
        v = self.rot[:2, :2] @ self.v0
        n = float(np.linalg.norm(v))
        return np.array([v[0] / n, v[1] / n, 0.0]) if n > 1e-9 else self.rot[:, 0]

    def paper_fell(self) -> bool:
        """Won & Lee 2019's fall: a walker's floor contact of any body other than the feet (the
        quadruped's shins included); for a swimmer, `fell`. Reported beside the task's own rule
        by `morphmimic evaluate` (`fall_down_pct_paper_rule`)."""
        if self.character.is_swimmer:
            return self.fell()
        d = self.data
        for i in range(d.ncon):
            c = d.contact[i]
            if not (self.feet_contact[self.model.geom_bodyid[c.geom1]] and self.feet_contact[self.model.geom_bodyid[c.geom2]]):
                return True
        return False

    def fall_bodies(self) -> list[str]:
        """The names of the bodies whose contacts end the episode as a fall now (sorted; empty
        for a swimmer, whose fall is its root's distance): why a shape fell, for evaluation."""
        d, names = self.data, set()
        for i in range(d.ncon):
            c = d.contact[i]
            for b in (self.model.geom_bodyid[c.geom1], self.model.geom_bodyid[c.geom2]):
                if not self.allowed_contact[b]:
                    names.add(self.model.body(int(b)).name)
        return sorted(names)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        a = np.clip(np.nan_to_num(np.asarray(action, dtype=np.float64)), -self.cfg.imitate.action_clip, self.cfg.imitate.action_clip)
        self.data.ctrl[:] = self.ref_joints[1] + self.cfg.imitate.action_scale * a
        diverged = step_physics(self.model, self.data, self.cfg.substeps)
        self.k += 1
        if diverged:
            return diverged_step(self.obs_dim)
        self.com_hist.append(self.data.subtree_com[self.root_body].copy())
        self._refresh_reference()
        body_frame = self._body_frame()
        terms = self.reward_terms(body_frame)
        r_imit, r_task, r_reg = rewards.split(terms)
        fell = self.fell()
        obs = self._obs(body_frame)
        truncated = self.k >= self.cfg.episode_steps and not fell
        info = {"diverged": False, "fell": fell, "task_reward": r_task, "imitation_reward": r_imit, "reg_reward": r_reg,
                "terms": terms, "fell_paper_rule": fell or (self.rules_differ and self.paper_fell())}
        if fell and not self.character.is_swimmer:
            info["fall_bodies"] = self.fall_bodies()
        return obs, r_imit + r_task + r_reg, fell, truncated, info

    def _obs_safe(self) -> np.ndarray:
        try:
            obs = self._obs()
        except Exception:  # NOTE: a diverged state may hold NaN/inf that numpy chokes on
            return np.zeros(self.obs_dim, np.float32)
        return np.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0)

    # ---- shape change during the episode (Won & Lee 2019 section 3, METHOD.md A) ----

    def set_shape(self, shape: np.ndarray) -> None:
        """Morph the body to `shape` `[P]` now, keeping the state (common.characters.morph) and
        the clip time; the reference is retargeted to the new body and shifted so its root
        stays where it was. The episode's parameter vector (in the observation) follows."""
        shape = np.asarray(shape, dtype=np.float64)
        old_root = self.ref_q[0][0:3].copy()
        self._cache.clear()  # NOTE: morph re-shapes the spec in place: cached characters share it
        ch, self.data = morph(self.character, shape, self.data)
        self._gains(ch)
        motion = references.play(ch, self.clip_id, self.timestep_s, self.retarget)
        norm = self._normalization(ch, shape)
        self._set_character(ch, motion, norm)
        new_root = self._ref_qpos(self.k * self.dt)[0][0:3]
        self.ref_offset = self.ref_offset + old_root - new_root
        self.ref_offset[2] = 0.0
        self._clear_table()
        self.params = np.concatenate([shape, self.params[self.n_shape :]])
        self._refresh_reference()


def stroke_model_for(task) -> StrokeModel | None:
    """The stroke-speed model a shape task (`common.tasks.base.TaskConfig`) uses: None unless
    `swimmer_speed = "stroke_fit"` with reward normalization on (the target speed is not scaled
    without it); ValueError if the rule is asked of a walker, StrokeModelError if the model
    file is missing or does not fit the task's shape parameters."""
    if task.imitate.swimmer_speed != "stroke_fit":
        return None
    preset = character_preset(task)
    if preset not in SWIMMERS:
        raise ValueError(f"--task.imitate.swimmer-speed stroke_fit: {preset!r} is not a swimmer; "
                         f"the rule applies to {', '.join(SWIMMERS)}")
    if not task.imitate.reward_normalization:
        return None
    space = ImitateEnv.param_space(task)
    return StrokeModel.load(preset, space.names[: space.dim - len(task.imitate.task_params)])
