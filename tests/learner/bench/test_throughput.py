"""The throughput bench's pure-simulation phase replays what the end-to-end run did."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from actors.config import ActorConfig
from common import wire
from common.policy import GaussianPolicy, policy_tensors
from common.tasks.registry import make_env, task_clips, task_space
from learner.bench import throughput as bench_throughput
from learner.presets import PRESETS
from sampler.shape_sampler import ShapeSampler


@pytest.mark.parametrize("preset", ["lower_biped-tiny", "executor-tiny"])
def test_pure_phase_replays_the_runs_policies_and_sampler_states(preset, monkeypatch):
    base = PRESETS[preset][1]
    cfg = dataclasses.replace(base, steps_per_iteration=64, ppo=dataclasses.replace(base.ppo, minibatch=64),
                              actors=ActorConfig(num_actors=1, envs_per_actor=2, unroll_length=16, draw_batch=4))
    space, clips = task_space(cfg.task), task_clips(cfg.task)
    env = make_env(cfg.task, seed=0)
    # A made-up end-to-end record of 4 iterations, each with its own policy and sampler state,
    # from a sampler seeded unlike the bench's own (so its buffer tells whose draws these are).
    rec = bench_throughput.Round()
    service = ShapeSampler(dataclasses.replace(cfg.sampler, seed=123), space, clips)
    for i in range(4):
        torch.manual_seed(i)
        policy = GaussianPolicy(env.obs_dim, env.act_dim, cfg.policy)
        rec.marks.append((float(i), {}))
        rec.weights.append(wire.WeightsMsg(policy_version=i, tensors=policy_tensors(policy)))
        service.draw(3)
        rec.sampler_states.append(service.state_dict())

    seen: dict[str, list] = {"versions": [], "clips": [], "params": []}

    class Recording(bench_throughput.RolloutWorker):
        def __init__(self, actor_id, task, policy_cfg, actor_cfg, draw, seed=0):
            def recorded():
                params, clip, start = draw()
                seen["params"].append(np.asarray(params))
                seen["clips"].append(clip)
                return params, clip, start

            super().__init__(actor_id, task, policy_cfg, actor_cfg, recorded, seed)

        def set_weights(self, msg):
            seen["versions"].append(msg.policy_version)
            super().set_weights(msg)

    monkeypatch.setattr(bench_throughput, "RolloutWorker", Recording)
    out = bench_throughput.pure_simulation(cfg, rec, warmup_iterations=1)

    # Timed: the iterations between marks 1-2 and 2-3, each 2 unrolls of 2 envs x 16 steps.
    assert out["steps"] == 2 * 2 * 32 and out["steps_per_s"] > 0
    assert seen["versions"] == [0, 1, 2]  # the warm-up iteration (untimed), then the timed ones
    assert len(seen["params"]) > 2  # episodes ended and drew again after the construction's resets
    replayed = [p for p in seen["params"][2:] if any(np.allclose(p, row) for row in service.buffer)]
    assert replayed, "no draw came from the recorded sampler states"
    if clips:
        assert all(c in {cid for cid, _ in clips} for c in seen["clips"])
    else:
        assert all(c is None for c in seen["clips"])
