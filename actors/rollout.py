"""`RolloutWorker`: a batch of environments stepped in lockstep by one batched policy forward
per control step, packed into `UnrollMsg`s. No sockets here: the actor process (or the serial
driver) moves the messages.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from actors.config import ActorConfig
from common import wire
from common.policy import GaussianPolicy, PolicyConfig, load_policy_tensors
from common.tasks.base import TaskConfig
from common.tasks.registry import make_env

DrawFn = Callable[[], tuple[np.ndarray, str | None]]
"""Returns the next episode's parameter vector and clip id (or None)."""


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
        self.envs = [make_env(task, seed=seed * 10_007 + i) for i in range(cfg.envs_per_actor)]
        env = self.envs[0]
        self.obs_dim, self.act_dim, self.n_params = env.obs_dim, env.act_dim, env.space.dim
        self.policy = GaussianPolicy(self.obs_dim, self.act_dim, policy_cfg)
        self.policy_version = -1
        self.seq = 0
        self.env_steps = 0
        self.rng = np.random.default_rng(seed)
        self._obs = np.zeros((len(self.envs), self.obs_dim), np.float32)
        self._params = np.zeros((len(self.envs), self.n_params), np.float32)
        self._ep_return = np.zeros(len(self.envs))
        self._ep_length = np.zeros(len(self.envs), np.int64)
        for i in range(len(self.envs)):
            self._reset_env(i)

    def set_weights(self, msg: wire.WeightsMsg) -> None:
        load_policy_tensors(self.policy, msg.tensors)
        self.policy_version = msg.policy_version

    def _reset_env(self, i: int) -> None:
        params, clip_id = self.draw()
        obs, _ = self.envs[i].reset(int(self.rng.integers(2**31)), params, clip_id)
        self._obs[i] = obs
        self._params[i] = params
        self._ep_return[i] = 0.0
        self._ep_length[i] = 0

    def collect(self) -> wire.UnrollMsg:
        """Step every environment `unroll_length` times; return the unroll."""
        T, N = self.cfg.unroll_length, len(self.envs)
        obs = np.zeros((T, N, self.obs_dim), np.float32)
        next_obs = np.zeros_like(obs)
        actions = np.zeros((T, N, self.act_dim), np.float32)
        logp = np.zeros((T, N), np.float32)
        rewards = np.zeros((T, N), np.float32)
        terminated = np.zeros((T, N), bool)
        truncated = np.zeros((T, N), bool)
        params = np.zeros((T, N, self.n_params), np.float32)
        returns: list[float] = []
        lengths: list[int] = []
        divergences = 0
        for t in range(T):
            obs[t] = self._obs
            params[t] = self._params
            act, lp = self.policy.act(self._obs)
            if not np.isfinite(act).all():
                # NOTE: never feed NaN to MuJoCo: it would reset silently and poison the unroll.
                act = np.nan_to_num(act, nan=0.0, posinf=0.0, neginf=0.0)
                lp = np.nan_to_num(lp, nan=0.0)
            actions[t], logp[t] = act, lp
            for i, env in enumerate(self.envs):
                o, r, term, trunc, info = env.step(act[i])
                diverged = bool(info.get("diverged")) or not np.isfinite(o).all() or not np.isfinite(r)
                if diverged:
                    # The simulator failed: the episode terminates with reward 0 (as the tasks'
                    # `diverged_step`), so the policy learns to avoid what blows the simulation up
                    # rather than being paid its value. The guard also covers a non-finite
                    # observation or reward a task did not flag; next_obs keeps the last good one.
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
        segments = [seg for env in self.envs if hasattr(env, "drain_segments") for seg in env.drain_segments()]
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
            segment_clips=[clip for clip, _ in segments],
            segment_tracked=[int(tracked) for _, tracked in segments],
        )
        self.seq += 1
        return msg


def configure_torch(threads: int) -> None:
    torch.set_num_threads(threads)
