"""`ShapeBatch`: an actor's N shape-task environments (Won & Lee 2019, METHOD.md A) stepped as one
batch (`common.tasks.batch.BatchEnv`).

Environment i is an `ImitateEnv(cfg, seeds[i])` of its own: every episode draws a new body
shape, so each environment keeps its own MjModel and MjData, its own retargeted reference and
its own random generator, and `reset_one` is that environment's `reset` (the same rng draws,
character cache and reference state start). A step then works on all N at once:

- the PD targets `q_ref(t + dt) + action_scale a` and the action clipping as `[N, nu]` arrays;
- physics one environment after another (`mj_step` x substeps through MuJoCo's C API: the
  models differ), each followed by the gather of what the state and reward read from MjData
  (qpos, qvel, end effectors, centre of mass and its velocity, actuator forces, contacts);
- the reference from each environment's episode table (`references.GridReference`: one row
  per control step, filled at reset and as the episode goes on) at the rows of its step;
- the state s = (s_b, s_d, s_s), the six reward terms and the termination as numpy over N.

The body shapes of one preset share the joint layout, end effectors and body tree, so their
arrays stack. Every value is the same float computation as `ImitateEnv.step`'s on the same
numbers (batched matmul runs BLAS per matrix as the single environment's does; dot products
are batched matmuls, not einsum, which sums in another order), so environment i's observations,
rewards, terminations and infos are bit for bit its single environment's
(tests/common/tasks/shape/test_batch.py).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import mujoco
import numpy as np

from common.tasks.base import TaskConfig, step_physics
from common.tasks.shape import rewards
from common.tasks.shape.env import ImitateEnv


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Row-wise dot products `[N]` of `[N, K]` arrays, each summed as the 1-D `x[i] @ y[i]` of a
    contiguous row is (BLAS ddot: strided rows would take numpy's own loop, another order)."""
    x, y = np.ascontiguousarray(x), np.ascontiguousarray(y)
    return np.matmul(x[:, None, :], y[:, :, None])[:, 0, 0]


def _mean_sq(x: np.ndarray) -> np.ndarray:
    """`rewards.mean_sq` of each row of `[N, K]`."""
    return _dot(x, x) / max(1, x.shape[1])


def _apply(frames: np.ndarray, v: np.ndarray) -> np.ndarray:
    """`frames[i] @ v[i]`: `[N, a, b]` matrices on `[N, b]` vectors -> `[N, a]`."""
    return np.matmul(frames, v[:, :, None])[:, :, 0]


class ShapeBatch:
    """`BatchEnv` of the shape tasks; see the module docstring."""

    def __init__(self, cfg: TaskConfig, seeds: Sequence[int]):
        if not seeds:
            raise ValueError("a batch needs at least one environment")
        self.cfg = cfg
        self.envs = [ImitateEnv(cfg, int(seed)) for seed in seeds]
        first = self.envs[0]
        self.n, self.obs_dim, self.act_dim, self.space = len(self.envs), first.obs_dim, first.act_dim, first.space
        self.layout, self.look, self.dt = first.layout, first._look, first.dt
        self.swimmer = first.character.is_swimmer
        self.history = int(first.com_hist.maxlen)
        if self.history < 2:
            raise ValueError(f"control_hz={cfg.control_hz}: the COM velocity window holds fewer than two samples")
        self.weights = np.array(first.weights, dtype=np.float64)
        self.sigmas = np.array(first.sigmas, dtype=np.float64)
        self.tau_scale = first.tau_scale
        self.slices = first.ref.slices
        n, model = self.n, first.model
        self.k = np.zeros(n, np.int64)
        self.params = np.zeros((n, len(first.params)))
        self.target_vel = np.zeros((n, 2))
        self.course_dir = np.zeros((n, 3))
        self.length_m = np.zeros(n)
        self.asym = np.ones(n)
        self.mass_ratio = np.ones(n)
        self.tau0 = np.zeros(n)
        self.speed = np.ones(n)
        self.duration = np.ones(n)
        self.com_hist = np.zeros((n, self.history, 3))
        self.com_count = np.zeros(n, np.int64)
        self.com_head = np.zeros(n, np.int64)
        self.ctrl_ref = np.zeros((n, model.nu))
        """`[N, nu]` reference joint vector one step ahead of each environment: its PD target."""
        n_ee = len(first.ee_ids)
        self._qpos, self._qvel = np.zeros((n, model.nq)), np.zeros((n, model.nv))
        self._ee, self._com, self._linvel = np.zeros((n, n_ee, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        self._force, self._rot = np.zeros((n, model.nu)), np.zeros((n, 9))
        self._ref = np.zeros((n, 2 + len(self.look) - 1, first.ref.width))
        for i in range(n):
            self._pull(i)

    def _pull(self, i: int) -> None:
        """Take environment i's episode state after its reset: parameters, per-episode
        constants, the COM history and the PD target of its first step."""
        env = self.envs[i]
        self.k[i] = env.k
        self.params[i] = env.params
        self.target_vel[i] = env.target_velocity()
        self.course_dir[i] = env.course_direction()
        self.length_m[i] = env.length_m
        self.asym[i], self.mass_ratio[i] = env.norm.asym, env.norm.mass_ratio
        self.tau0[i], self.speed[i], self.duration[i] = env.tau0, env.speed, env.motion.duration_s
        self.com_hist[i, : len(env.com_hist)] = np.array(env.com_hist)
        self.com_count[i] = len(env.com_hist)
        self.com_head[i] = len(env.com_hist) % self.history
        self.ctrl_ref[i] = env.ref_joints[1]

    def reset_one(self, i: int, seed: int | None, params: np.ndarray, clip_id: str | None = None,
                  start_s: float | None = None) -> np.ndarray:
        """Environment i's `ImitateEnv.reset`: a new body shape, its reference and the start state
        (`start_s` must be None: the shape tasks draw their own phase)."""
        if start_s is not None:
            raise ValueError(f"start_s = {start_s!r}: the shape tasks take no start time (give None)")
        obs, _ = self.envs[i].reset(seed, params, clip_id)
        self._pull(i)
        return obs

    def drain_segments(self) -> list[tuple[str, bool, float]]:
        """No clip segments: each shape task plays one looping clip."""
        return []

    def _gather(self, i: int) -> tuple[bool, bool]:
        """Read environment i's state after its physics into the batch arrays and look its
        reference up at the rows of its step; (fell, fell by Won & Lee's rule) for a walker."""
        env = self.envs[i]
        m, d = env.model, env.data
        self._qpos[i] = d.qpos
        self._qvel[i] = d.qvel
        self._ee[i] = d.xpos[env.ee_ids]
        self._com[i] = d.subtree_com[env.root_body]
        # NOTE: mj_step does not fill subtree_linvel (see ImitateEnv._obs).
        mujoco.mj_subtreeVel(m, d)
        self._linvel[i] = d.subtree_linvel[env.root_body]
        self._force[i] = d.actuator_force
        mujoco.mju_quat2Mat(self._rot[i], self._qpos[i, 3:7])
        row = int(self.k[i]) + 1
        env.ref.ensure(row + self.look[-1] + 2)
        self._ref[i] = env.ref.rows[[row, row + 1, *(row + x for x in self.look[1:])]]
        if self.swimmer or not d.ncon:
            return False, False
        bodies = m.geom_bodyid[d.contact.geom]
        fell = not env.allowed_contact[bodies].all()
        return fell, fell or (env.rules_differ and not env.feet_contact[bodies].all())

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        im = self.cfg.imitate
        a = np.clip(np.nan_to_num(np.asarray(actions, dtype=np.float64)), -im.action_clip, im.action_clip)
        ctrl = self.ctrl_ref + im.action_scale * a
        n = self.n
        diverged = np.zeros(n, bool)
        fell = np.zeros(n, bool)
        paper = np.zeros(n, bool)
        for i, env in enumerate(self.envs):
            env.data.ctrl[:] = ctrl[i]
            diverged[i] = step_physics(env.model, env.data, self.cfg.substeps)
        self.k += 1
        live = np.flatnonzero(~diverged)
        for i in live:
            fell[i], paper[i] = self._gather(i)
        with np.errstate(all="ignore"):
            obs, terms, course_off = self._compute(live)
        if self.swimmer:
            fell = (np.sqrt(_dot(course_off, course_off)) > im.max_root_deviation * self.length_m) if im.max_root_deviation > 0 \
                else np.zeros(n, bool)
            paper = fell
        r_imit = terms[:, 0] + terms[:, 1] + terms[:, 2]
        r_task = terms[:, 3] + terms[:, 4]
        r_reg = terms[:, 5]
        reward = r_imit + r_task + r_reg
        truncated = (self.k >= self.cfg.episode_steps) & ~fell
        infos: list[dict[str, Any]] = []
        for i in range(n):
            if diverged[i]:
                infos.append({"diverged": True, "fell": False})
                continue
            info = {"diverged": False, "fell": bool(fell[i]), "task_reward": float(r_task[i]),
                    "imitation_reward": float(r_imit[i]), "reg_reward": float(r_reg[i]),
                    "terms": dict(zip(rewards.TERMS, terms[i].tolist())), "fell_paper_rule": bool(paper[i])}
            if fell[i] and not self.swimmer:
                info["fall_bodies"] = self.envs[i].fall_bodies()
            infos.append(info)
        obs[diverged] = 0.0
        reward[diverged] = 0.0
        fell[diverged], truncated[diverged] = True, False
        return obs, reward, fell, truncated, infos

    def _compute(self, live: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Observations `[N, obs_dim]` float32, the six weighted reward terms `[N, 6]` and the
        swimmers' course offsets `[N, 3]` at the state gathered, for all N (a diverged
        environment's rows are overwritten by the caller). Won & Lee 2019 (METHOD.md A)."""
        im, sl, lay = self.cfg.imitate, self.slices, self.layout
        n = self.n
        q, v = self._qpos, self._qvel
        # The COM history (`ImitateEnv.com_hist`, a deque of `history` samples) as a ring.
        self.com_hist[live, self.com_head[live]] = self._com[live]
        self.com_head[live] = (self.com_head[live] + 1) % self.history
        self.com_count[live] = np.minimum(self.com_count[live] + 1, self.history)
        self.ctrl_ref[live] = self._ref[live, 1, sl["j"]]
        ar = np.arange(n)
        newest = self.com_hist[ar, (self.com_head - 1) % self.history]
        oldest = self.com_hist[ar, (self.com_head - self.com_count) % self.history]
        com_avg = (newest[:, :2] - oldest[:, :2]) / ((self.com_count - 1) * self.dt)[:, None]

        rot = self._rot.reshape(n, 3, 3)
        yaw = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])
        c, s = np.cos(yaw), np.sin(yaw)
        frame = np.zeros((n, 3, 3))
        frame[:, 0, 0], frame[:, 0, 1], frame[:, 1, 0], frame[:, 1, 1], frame[:, 2, 2] = c, -s, s, c, 1.0
        frame_t = frame.transpose(0, 2, 1)
        ee = np.matmul(self._ee - q[:, None, 0:3], frame)

        ref = self._ref
        qref = ref[:, 0, sl["q"]]
        balls = np.concatenate([q[:, None, 3:7], q[:, lay.ball_qpos]], axis=1)
        balls_ref = np.concatenate([qref[:, None, 3:7], qref[:, lay.ball_qpos]], axis=1)
        angles = 2.0 * np.arccos(np.minimum(np.maximum(np.abs(np.sum(balls * balls_ref, axis=-1)), 0.0), 1.0))
        pose = np.concatenate([angles, q[:, lay.hinge_qpos] - qref[:, lay.hinge_qpos]], axis=1)
        d_ee = (ee - ref[:, 0, sl["ee"]].reshape(ee.shape)).reshape(n, -1)
        errors = np.stack([
            _mean_sq(pose),
            _mean_sq(v[:, 6:] - ref[:, 0, sl["qvel"]][:, 6:]),
            np.sum(d_ee * d_ee, axis=1) / 3.0,
            _mean_sq(com_avg - self.target_vel),
            _mean_sq(frame[:, :2, 0] - ref[:, 0, sl["facing"]]),
            _mean_sq(self._force / self.tau_scale),
        ], axis=1)
        if im.reward_normalization:
            errors[:, 4] = errors[:, 4] / self.asym
            errors[:, 5] = errors[:, 5] * self.mass_ratio
        terms = self.weights * np.exp(-errors / self.sigmas)

        offset = q[:, 0:3] - qref[:, 0:3]
        course_off = offset - _dot(offset, self.course_dir)[:, None] * self.course_dir

        local = np.matmul(frame_t, rot)
        root = [q[:, 2:3], local[:, :, 0], local[:, :, 1], _apply(frame_t, v[:, 0:3]), _apply(frame_t, _apply(rot, v[:, 3:6]))]
        refs = []
        for r in (0, 2, 3):
            ref_rot = np.matmul(frame_t, ref[:, r, sl["rmat"]].reshape(n, 3, 3))
            refs += [ref[:, r, sl["j"]], ref[:, r, sl["q"]][:, 2:3], ref_rot[:, :, 0], ref_rot[:, :, 1]]
        frame2_t = frame[:, :2, :2].transpose(0, 2, 1)
        t = self.speed * self.k * self.dt
        phase = [2.0 * math.pi * ((t0 + ti) / dur) for t0, ti, dur in zip(self.tau0.tolist(), t.tolist(), self.duration.tolist())]
        parts = [self.params, *root, lay.to_vector(q), v[:, 6:], ee.reshape(n, -1), *refs, _apply(frame2_t, self.target_vel),
                 _apply(frame2_t, com_avg), _apply(frame_t, self._linvel),
                 np.array([[math.sin(p), math.cos(p)] for p in phase])]
        if im.observe_course:
            parts.append(_apply(frame_t, course_off) / self.length_m[:, None])
        return np.concatenate(parts, axis=1).astype(np.float32), terms, course_off
