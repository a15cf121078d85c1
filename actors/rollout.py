"""`RolloutWorker`: a batch of environments (`common.tasks.batch.BatchEnv`) stepped in lockstep
by one batched policy forward per control step, packed into `UnrollMsg`s. No sockets here: the
actor process (or the serial driver) moves the messages.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from actors.config import ActorConfig
from common import wire
from common.policy import GaussianPolicy, PolicyConfig, load_policy_tensors
from common.tasks.base import TaskConfig
from common.tasks.registry import make_batch_env

DrawFn = Callable[[], tuple[np.ndarray, str | None, float | None]]
"""Returns the next episode's parameter vector, clip id (or None) and start time in s (or None)."""


class RolloutWorker:
    def __init__(
        self,
        actor_id: int,
        task: TaskConfig,
        policy_cfg: PolicyConfig,
        cfg: ActorConfig,
        draw: DrawFn,
        seed: int = 0,
    ):
        self.actor_id = actor_id
        self.cfg = cfg
        self.draw = draw
        self.batch = make_batch_env(task, [seed * 10_007 + i for i in range(cfg.envs_per_actor)])
        self.n_envs = self.batch.n
        self.obs_dim, self.act_dim, self.n_params = self.batch.obs_dim, self.batch.act_dim, self.batch.space.dim
        self.policy = GaussianPolicy(self.obs_dim, self.act_dim, policy_cfg)
        self.policy_version = -1
        self.seq = 0
        self.env_steps = 0
        self.rng = np.random.default_rng(seed)
        self._obs = np.zeros((self.n_envs, self.obs_dim), np.float32)
        self._params = np.zeros((self.n_envs, self.n_params), np.float32)
        self._clips: list[str | None] = [None] * self.n_envs
        """The clip each environment's episode was drawn with (None: the task has no clips)."""
        self._ep_return = np.zeros(self.n_envs)
        self._ep_length = np.zeros(self.n_envs, np.int64)
        for i in range(self.n_envs):
            self._reset_env(i)

    def set_weights(self, msg: wire.WeightsMsg) -> None:
        load_policy_tensors(self.policy, msg.tensors)
        self.policy_version = msg.policy_version

    def _reset_env(self, i: int) -> None:
        params, clip_id, start_s = self.draw()
        self._obs[i] = self.batch.reset_one(i, int(self.rng.integers(2**31)), params, clip_id, start_s)
        self._params[i] = params
        self._clips[i] = clip_id
        self._ep_return[i] = 0.0
        self._ep_length[i] = 0

    def collect(self) -> wire.UnrollMsg:
        """Step every environment `unroll_length` times; return the unroll."""
        T, N = self.cfg.unroll_length, self.n_envs
        obs = np.zeros((T, N, self.obs_dim), np.float32)
        next_obs = np.zeros_like(obs)
        actions = np.zeros((T, N, self.act_dim), np.float32)
        logp = np.zeros((T, N), np.float32)
        rewards = np.zeros((T, N), np.float32)
        terminated = np.zeros((T, N), bool)
        truncated = np.zeros((T, N), bool)
        params = np.zeros((T, N, self.n_params), np.float32)
        step_clips = np.full((T, N), -1, np.int32)
        clip_index: dict[str, int] = {}
        returns: list[float] = []
        lengths: list[int] = []
        divergences = 0
        for t in range(T):
            obs[t] = self._obs
            params[t] = self._params
            for i, clip in enumerate(self._clips):
                if clip is not None:
                    step_clips[t, i] = clip_index.setdefault(clip, len(clip_index))
            act, lp = self.policy.act(self._obs)
            if not np.isfinite(act).all():
                # NOTE: never feed NaN to MuJoCo: it would reset silently and poison the unroll.
                act = np.nan_to_num(act, nan=0.0, posinf=0.0, neginf=0.0)
                lp = np.nan_to_num(lp, nan=0.0)
            actions[t], logp[t] = act, lp
            step_obs, step_rewards, step_term, step_trunc, infos = self.batch.step(act)
            for i in range(N):
                o, r, term, trunc = step_obs[i], float(step_rewards[i]), bool(step_term[i]), bool(step_trunc[i])
                diverged = bool(infos[i].get("diverged")) or not np.isfinite(o).all() or not np.isfinite(r)
                if diverged:
                    # The simulator failed: the episode ends with no future (METHOD.md A lists
                    # simulation failure with the falls among the terminations), so the policy
                    # learns to avoid what blows the simulation up rather than being paid its value.
                    divergences += 1
                    o, r, term, trunc = self._obs[i], 0.0, True, False
                next_obs[t, i] = o
                rewards[t, i] = r
                terminated[t, i], truncated[t, i] = term, trunc and not term
                self._ep_return[i] += r
                self._ep_length[i] += 1
                if term or trunc:
                    returns.append(float(self._ep_return[i]))
                    lengths.append(int(self._ep_length[i]))
                    self._reset_env(i)
                else:
                    self._obs[i] = o
        self.env_steps += T * N
        segments = self.batch.drain_segments()
        msg = wire.UnrollMsg(
            actor_id=self.actor_id,
            seq=self.seq,
            policy_version=self.policy_version,
            obs=obs,
            next_obs=next_obs,
            actions=actions,
            logp=logp,
            rewards=rewards,
            terminated=terminated,
            truncated=truncated,
            params=params,
            episode_returns=returns,
            episode_lengths=lengths,
            divergences=divergences,
            segment_clips=[clip for clip, _, _ in segments],
            segment_tracked=[int(tracked) for _, tracked, _ in segments],
            segment_times=[at for _, _, at in segments],
            clip_names=list(clip_index),
            step_clips=step_clips if clip_index else np.zeros((0, 0), np.int32),
        )
        self.seq += 1
        return msg


def configure_torch(threads: int) -> None:
    torch.set_num_threads(threads)
