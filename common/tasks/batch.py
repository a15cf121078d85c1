"""Batched environments: an actor's N environments of one task stepped as one batch.

`BatchEnv` is what the rollout worker drives: `step(actions [N, A])` advances every environment
one control step and returns arrays over all N; `reset_one(i, ...)` starts environment i's next
episode (resets stay per environment, between steps). Environment i of a batch made with
`seeds` behaves as `make_env(cfg, seeds[i])` stepped alone with the same actions and resets:
a task's own batch (registered as `TaskEntry.batch`) computes observations, rewards,
termination and actuation as array operations over N, and a test holds it equal to its single
environment. `LoopBatch` is the batch of any task that has none: a loop over single environments.
"""

from __future__ import annotations

from typing import Any, Protocol, Sequence

import numpy as np

from common.params import ParamSpace
from common.tasks.base import Env


class BatchEnv(Protocol):
    n: int
    obs_dim: int
    act_dim: int
    space: ParamSpace

    def reset_one(self, i: int, seed: int | None, params: np.ndarray, clip_id: str | None = None,
                  start_s: float | None = None) -> np.ndarray:
        """Start environment i's next episode (`Env.reset`) on `clip_id` from `start_s` (s; None:
        the environment draws one; tasks without start times take only None); its first
        observation `[obs_dim]`."""
        ...

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """One control step of every environment with `actions` `[N, act_dim]`: observations
        `[N, obs_dim]` float32 (an ended episode's last), rewards `[N]`, terminated `[N]`,
        truncated `[N]` and one info dict per environment (`Env.step`'s)."""
        ...

    def drain_segments(self) -> list[tuple[str, bool, float]]:
        """The clip segments every environment ended since the last call, (clip id, tracked, clip
        time at the end) (`ExecutorEnv.drain_segments`; empty for tasks without clips)."""
        ...


class LoopBatch:
    """N single environments behind the `BatchEnv` interface, stepped one after another."""

    def __init__(self, envs: Sequence[Env]):
        if not envs:
            raise ValueError("a batch needs at least one environment")
        self.envs = list(envs)
        self.n = len(self.envs)
        first = self.envs[0]
        self.obs_dim, self.act_dim, self.space = first.obs_dim, first.act_dim, first.space

    def reset_one(self, i: int, seed: int | None, params: np.ndarray, clip_id: str | None = None,
                  start_s: float | None = None) -> np.ndarray:
        if start_s is None:
            obs, _ = self.envs[i].reset(seed, params, clip_id)
        else:
            obs, _ = self.envs[i].reset(seed, params, clip_id, start_s)
        return obs

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        obs = np.zeros((self.n, self.obs_dim), np.float32)
        rewards = np.zeros(self.n)
        terminated = np.zeros(self.n, bool)
        truncated = np.zeros(self.n, bool)
        infos = []
        for i, env in enumerate(self.envs):
            obs[i], rewards[i], terminated[i], truncated[i], info = env.step(actions[i])
            infos.append(info)
        return obs, rewards, terminated, truncated, infos

    def drain_segments(self) -> list[tuple[str, bool, float]]:
        return [seg for env in self.envs if hasattr(env, "drain_segments") for seg in env.drain_segments()]
