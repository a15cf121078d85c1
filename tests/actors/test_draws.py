"""The actor's draw cache and its path into the executor: a draw's clip and start time from the
sampler (`ShapeSampler.draw_episodes`, time bins on) become the episode's clip and start
(`env.reset(..., clip_id, start_s)`), and every start the sampler can draw is one the
environment accepts (the manifest's clip lengths against the loaded clips')."""

from __future__ import annotations

import dataclasses

import numpy as np

from actors.config import ActorConfig
from actors.draws import DrawCache
from actors.rollout import RolloutWorker
from common.policy import PolicyConfig
from common.rpc import ServiceUnavailable
from common.tasks.registry import make_env, task_clip_durations, task_clips, task_space
from learner.presets import PRESETS
from sampler.config import SamplerConfig
from sampler.shape_sampler import ShapeSampler
from sampler.time_bins import END_MARGIN_S

TASK = PRESETS["executor-tiny"][1].task


def test_the_cache_hands_out_clip_and_start_and_keeps_them_through_an_outage():
    space = task_space(TASK)
    replies = [(space.uniform(np.random.default_rng(0), 2), ["a", "b"], [0.5, 1.5]),
               (space.uniform(np.random.default_rng(1), 2), ["c", "d"], [])]
    calls = []

    def fetch(n):
        calls.append(n)
        if len(calls) == 2:
            raise ServiceUnavailable("down")
        return replies.pop(0)

    cache = DrawCache(fetch, space, batch=2)
    assert [cache()[1:] for _ in range(2)] == [("a", 0.5), ("b", 1.5)]
    assert [cache()[1:] for _ in range(2)] == [("a", 0.5), ("b", 1.5)]  # the outage: the last batch again
    assert cache.outages == 1
    assert [cache()[1:] for _ in range(2)] == [("c", None), ("d", None)]  # no starts: the env draws them


def test_sampled_starts_reach_the_executor_and_every_clip_takes_its_latest_start():
    durations = task_clip_durations(TASK)
    clips = task_clips(TASK)
    assert set(durations) == {c for c, _ in clips}
    env = make_env(TASK, seed=0)
    for cid, _ in clips:  # the latest start the sampler draws is inside the loaded clip
        env.reset(0, env.space.default_array, cid, durations[cid] - END_MARGIN_S)
        assert env.scheduler.t0 == durations[cid] - END_MARGIN_S
    cfg = dataclasses.replace(SamplerConfig(n_mcmc=16, n_chains=4, burn_in=4, vm_fit_steps=1, probe_points=8), time_bin_s=0.5)
    sampler = ShapeSampler(cfg, task_space(TASK), clips, durations)
    drawn = []

    def fetch(n):
        out = sampler.draw_episodes(n)
        drawn.extend(zip(out[1], out[2]))
        return out

    worker = RolloutWorker(0, TASK, PolicyConfig(hidden=(16,)), ActorConfig(envs_per_actor=2, unroll_length=4),
                           DrawCache(fetch, task_space(TASK), batch=2), seed=0)
    for i, (cid, start) in enumerate(drawn[:2]):
        s = worker.batch.envs[i].scheduler
        assert (s.clip_id, s.t0) == (cid, start)
