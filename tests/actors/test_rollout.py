"""The rollout worker on a real MuJoCo environment: one batched forward per step, unroll
shapes, and a simulator divergence turned into a terminated, counted, reset episode."""

from __future__ import annotations

import numpy as np

from actors.config import ActorConfig
from actors.rollout import RolloutWorker
from common.policy import PolicyConfig
from common.tasks.base import TaskConfig
from common.tasks.registry import task_space


def _worker(envs: int = 3, T: int = 20) -> RolloutWorker:
    space = task_space(TaskConfig())
    rng = np.random.default_rng(0)
    return RolloutWorker(0, TaskConfig(), PolicyConfig(hidden=(16,)), ActorConfig(envs_per_actor=envs, unroll_length=T),
                         lambda: (space.uniform(rng, 1)[0], None, None), seed=0)


def test_unroll_shapes_and_episode_statistics():
    w = _worker()
    msg = w.collect()
    assert msg.obs.shape == (20, 3, 12) and msg.actions.shape == (20, 3, 2) and msg.params.shape == (20, 3, 2)
    msg = w.collect()
    msg = w.collect()  # 60 steps > the 50-step episode: every env finished one
    assert len(msg.episode_returns) == 3 and msg.episode_lengths == [50, 50, 50]
    assert msg.truncated.sum() == 3 and not msg.terminated.any()
    assert np.isfinite(msg.obs).all() and msg.seq == 2


def test_divergence_terminates_resets_and_is_counted():
    w = _worker(envs=2, T=5)
    w.batch.envs[0].model.actuator_gear[:, 0] = 1e30  # a torque MuJoCo cannot integrate
    msg = w.collect()
    assert msg.divergences >= 1
    assert msg.terminated[:, 0].any() and not msg.truncated[:, 0].any()  # no bootstrap from a blow-up
    assert np.isfinite(msg.next_obs).all() and np.isfinite(msg.rewards).all()
    assert msg.divergences == int(msg.terminated[:, 0].sum())
    assert not msg.terminated[:, 1].any()
