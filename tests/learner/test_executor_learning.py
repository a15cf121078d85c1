"""The executor learns on a step budget: serial-mode PPO on one slow clip (the MASS balance, on
the humanoid, torques) must lift the deterministic return above what an untrained policy gets.

The return is read with the training task's rule: termination waits 30 control steps, so it
measures how well the body tracks through its first half second. Measured (2026-12-02, 40 x 4096
steps, 142 s beside a training run): untrained 13.4-13.7, trained 15.3-15.6 on five starts.
Neither survived past the grace at that budget; the threshold sits between the two."""

from __future__ import annotations

import dataclasses

import pytest

from common.policy import GaussianPolicy
from common.tasks.executor.rewards import TERMS
from common.tasks.registry import make_env
from learner import checkpoint
from learner.presets import PRESETS
from learner.train import train

CLIP = "humanoid/mass_balance"
STEPS = 40 * 4096


def _mean_return(policy: GaussianPolicy, task, starts=(0.0, 0.5, 1.0, 1.5, 2.0)) -> float:
    env = make_env(task, seed=0)
    total = 0.0
    for i, start in enumerate(starts):
        obs, _ = env.reset(i, env.space.default_array, CLIP, start)
        for _ in range(600):
            action, _ = policy.act(obs[None], deterministic=True)
            obs, r, term, trunc, _ = env.step(action[0])
            total += r
            if term or trunc:
                break
    return total / len(starts)


@pytest.mark.slow
def test_executor_learns_to_track_a_clip_within_step_budget(tmp_path):
    base = PRESETS["executor"][1]
    # NOTE: all five terms watched (UniCon's rule, as when the thresholds were measured), not the preset's four
    ex = dataclasses.replace(base.task.executor, clips=(CLIP,), reactive_init=False, terminate_on=TERMS)
    cfg = dataclasses.replace(
        base, name="learn", runs_dir=str(tmp_path), mode="serial", quiet=True, total_env_steps=STEPS,
        steps_per_iteration=4096, checkpoint_every=1000, task=dataclasses.replace(base.task, executor=ex),
        actors=dataclasses.replace(base.actors, num_actors=1, envs_per_actor=16),
    )
    env = make_env(cfg.task, seed=0)
    untrained = GaussianPolicy(env.obs_dim, env.act_dim, cfg.policy)
    assert train(cfg) == 0
    _, state = checkpoint.load_latest(tmp_path / "learn" / "ckpt")
    assert state["env_steps"] >= STEPS
    trained = GaussianPolicy(env.obs_dim, env.act_dim, cfg.policy)
    trained.load_state_dict(state["policy"])
    before, after = _mean_return(untrained, cfg.task), _mean_return(trained, cfg.task)
    print(f"mean return on {CLIP}: untrained {before:.2f}, after {STEPS} steps {after:.2f}")
    assert after > THRESHOLD > before


THRESHOLD = 14.5
"""Between the untrained (13.4-13.7) and trained (15.3-15.6) returns measured (module docstring)."""
