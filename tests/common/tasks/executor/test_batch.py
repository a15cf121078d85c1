"""`ExecutorBatch` against N separate `ExecutorEnv`s: the same seeds, reset calls (named and
drawn clips), random actions and resets on ends and by force give the same observations,
rewards, ends, clip ids, end reasons and drained clip segments, bit for bit, for the torque
("executor"), PD ("executor-pd"), track ("executor-track": action-rate penalty, previous
action observed, truncation at a clip's end) and shape ("executor-shape": a body per shape drawn
at each reset, clips retargeted onto it, on three clips so that it stays quick) presets; and the
registry builds it for the executor."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from common.tasks.executor.batch import ExecutorBatch
from common.tasks.executor.env import ExecutorEnv
from common.tasks.registry import make_batch_env
from learner.presets import PRESETS

SEEDS = [3, 11, 12, 40]
SHAPE_CLIPS = ("humanoid3d_walk", "humanoid3d_run", "humanoid3d_kick")


def task(preset: str):
    cfg = PRESETS[preset][1].task
    if cfg.body.vary_shape:  # every new (clip, shape) is retargeted, by the batch and by each env alone
        cfg = dataclasses.replace(cfg, executor=dataclasses.replace(cfg.executor, clips=SHAPE_CLIPS))
    return dataclasses.replace(cfg, episode_s=2.0)  # time limits too, within the test's steps


@pytest.mark.parametrize("preset", ["executor", "executor-pd", "executor-track", "executor-shape"])
def test_batch_steps_as_its_environments_alone(preset: str) -> None:
    cfg = task(preset)
    batch = ExecutorBatch(cfg, SEEDS)
    alone = [ExecutorEnv(cfg, s) for s in SEEDS]
    clips = [c for c, _ in alone[0].clip_list[:3]]
    # Three shapes, so environments meet each other's (clip, shape) in the batch's shared cache;
    # one each time the space is pinned (then every draw is the base shape, as before).
    shapes = batch.space.uniform(np.random.default_rng(9), 3)
    pick = np.random.default_rng(10)
    rng = np.random.default_rng(7)
    plan = np.random.default_rng(8)

    def reset(i: int, seed: int | None) -> None:
        clip = clips[int(plan.integers(len(clips)))] if plan.random() < 0.5 else None
        params = shapes[int(pick.integers(len(shapes)))]
        got = batch.reset_one(i, seed, params, clip)
        want, info = alone[i].reset(seed, params, clip)
        assert np.array_equal(got, want)
        assert batch.envs[i].scheduler.clip_id == info["clip_id"]

    for i, s in enumerate(SEEDS):
        reset(i, s + 100)
    ends = rescheduled = 0
    for t in range(300):
        actions = rng.normal(0.0, 0.5, (len(SEEDS), batch.act_dim)).astype(np.float32)
        if t == 50:
            actions[1, 0] = np.nan  # the non-finite check
        obs, rewards, terminated, truncated, infos = batch.step(actions)
        for i, env in enumerate(alone):
            o, r, term, trunc, info = env.step(actions[i])
            assert np.array_equal(obs[i], o), (t, i)
            assert rewards[i] == r and terminated[i] == term and truncated[i] == trunc, (t, i)
            assert infos[i]["ended_by"] == info["ended_by"] and infos[i].get("clip_id") == info.get("clip_id")
            assert infos[i] == info, (t, i)
            rescheduled += bool(info.get("rescheduled"))
            if term or trunc or plan.random() < 0.01:
                ends += 1
                reset(i, None if plan.random() < 0.7 else int(plan.integers(1000)))
        if t % 50 == 49:
            assert batch.drain_segments() == [seg for env in alone for seg in env.drain_segments()]
    assert ends >= 8 and (rescheduled >= 1 or cfg.executor.at_clip_end == "stop")


def test_registry_builds_the_executor_batch() -> None:
    batch = make_batch_env(task("executor"), [0, 1])
    assert isinstance(batch, ExecutorBatch) and batch.n == 2
    assert batch.envs[1].model is batch.envs[0].model and batch.envs[1].data is not batch.envs[0].data


def test_with_shapes_each_environment_simulates_its_own_models() -> None:
    """A body per shape and environment (a step writes into its model, as with projectiles);
    the retargeted clips are shared: they depend on the clip and the shape alone."""
    batch = make_batch_env(task("executor-shape"), [0, 1])
    a, b = batch.envs
    assert a.model is not b.model and a.ref_model is not b.ref_model and a._references is b._references
    batch.reset_one(0, 0, np.array([1.2, 0.9]), "humanoid3d_walk")
    batch.reset_one(1, 0, np.array([1.2, 0.9]), "humanoid3d_walk")
    assert a.model is not b.model and a._motion("humanoid3d_walk") is b._motion("humanoid3d_walk")
    np.testing.assert_array_equal(a.model.geom_size, b.model.geom_size)


@pytest.mark.parametrize("preset", ["executor", "executor-pd"])
def test_a_divergence_in_the_batch_ends_that_environment_alone(preset: str) -> None:
    """One environment's simulation blows up mid-batch: it ends as alone (`diverged_step`), and
    the others' steps, computed without it, are still their own bit for bit."""
    cfg = task(preset)
    batch = ExecutorBatch(cfg, SEEDS[:3])
    alone = [ExecutorEnv(cfg, s) for s in SEEDS[:3]]
    rng = np.random.default_rng(0)
    for t in range(20):
        if t == 5:
            for env in (batch.envs[1], alone[1]):
                env.data.qvel[:] = 1e11  # above mjMAXVAL: MuJoCo warns and resets the state
        actions = rng.normal(0.0, 0.3, (3, batch.act_dim))
        obs, rewards, terminated, truncated, infos = batch.step(actions)
        assert infos[1]["diverged"] == (t == 5)
        for i, env in enumerate(alone):
            o, r, term, trunc, info = env.step(actions[i])
            assert np.array_equal(obs[i], o) and rewards[i] == r and (terminated[i], truncated[i]) == (term, trunc)
            assert infos[i] == info, (t, i)
            if term or trunc:
                batch.reset_one(i, None, batch.space.default_array)
                env.reset(None, batch.space.default_array)
