"""`ExecutorBatch`: an actor's N executor environments (`ExecutorEnv`, UniCon's motion executor,
METHOD.md B) stepped as one batch (`common.tasks.batch.BatchEnv`); training builds it through
`make_batch_env`.

Environment i is an `ExecutorEnv(cfg, seeds[i])` of its own: its generator (drawn in the same
order: reset's draws, the scheduler's at reschedules), its `DatasetScheduler` and its MjData.
The N share one compiled MjModel, the clip library and the clip manager (`ExecutorEnv(like=)`;
training never changes the model per environment), except with projectiles (a throw writes
into the model) and with `--task.body.vary-shape`, where each environment simulates the body
of its episode's shape (`bodies.ShapedBodies`, its own models) and the N share the clips
retargeted onto bodies (`bodies.ShapedReferences`: each depends on the clip and the shape
alone). A step is `env.step_envs`, the function `ExecutorEnv.step` runs as a batch of one:
- actuation (torques, or PD targets from the next frames), the characters' body kinematics
  features, the five reward terms, termination and the observations are array operations over
  the N environments, each environment's arithmetic the same as alone, so its observations,
  rewards and ends are those of `ExecutorEnv(cfg, seeds[i])` stepped alone bit for bit
  (tests/common/tasks/executor/test_batch.py holds it);
- physics runs per environment, `mj_step(model, data, nstep=substeps)`, then `step_physics`'s
  divergence check over the N at once: `mujoco.rollout` over the N datas measured slower on
  one thread (its state copies in and out cost more than the loop; docs/benchmarks.md);
- the target frames' body kinematics come from the scheduler's table of schedule rows
  (`DatasetScheduler.kinematics_at`): computed for `KINEMATICS_ROWS` rows of the episode's
  control grid at a time by the same MuJoCo calls on the same frames as the character's, and
  indexed by the step. Not a per-clip table interpolated by time: an interpolated body pose
  is not the kinematics of the interpolated joint angles, so such a table would change the
  targets; the rows are computed once per schedule instead, and a step only looks them up.
  Each row's kinematics, qpos, qvel and PD targets sit in one `TargetTable` the N share (slot
  i: environment i), so a step gathers all N environments' targets with one index per array;
- resets are per environment (`reset_one`: `ExecutorEnv.reset`).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from common.tasks.base import TaskConfig
from common.tasks.executor.env import ExecutorEnv, TargetTable, step_envs


class ExecutorBatch:
    """N executor environments as one `BatchEnv`; see the module docstring."""

    def __init__(self, cfg: TaskConfig, seeds: Sequence[int]):
        if not seeds:
            raise ValueError("a batch needs at least one environment")
        first = ExecutorEnv(cfg, seeds[0])
        self.envs = [first] + [ExecutorEnv(cfg, seed, like=first) for seed in seeds[1:]]
        self.n = len(self.envs)
        own = first._table
        if own is not None:  # one `TargetTable` for all: a step gathers every environment's targets at once
            table = TargetTable(self.n, own.rows, own.pos.shape[2], own.qpos.shape[2], own.qvel.shape[2],
                                first.nu, own.pd is not None)
            slots = np.arange(self.n)
            for i, env in enumerate(self.envs):
                table.copy_slot(env._table, i, env._slot)
                env._table, env._slot, env._slots = table, i, slots
        self.obs_dim, self.act_dim, self.space = first.obs_dim, first.act_dim, first.space

    def reset_one(self, i: int, seed: int | None, params: np.ndarray, clip_id: str | None = None,
                  start_s: float | None = None) -> np.ndarray:
        obs, _ = self.envs[i].reset(seed, params, clip_id, start_s)
        return obs

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        return step_envs(self.envs, actions)

    def drain_segments(self) -> list[tuple[str, bool, float]]:
        return [seg for env in self.envs for seg in env.drain_segments()]
