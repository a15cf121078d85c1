"""`ShapeBatch` steps N shape-task environments as one batch; environment i must behave bit for
bit as `ImitateEnv(cfg, seeds[i])` stepped alone with the same resets and actions."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from common.tasks.registry import make_batch_env
from common.tasks.shape.batch import ShapeBatch
from common.tasks.shape.env import ImitateEnv
from common.tasks.shape.presets import shape_task

SEEDS = [11, 12, 13]


def _pair(preset: str, episode_s: float, **imitate) -> tuple[ShapeBatch, list[ImitateEnv]]:
    cfg = shape_task(preset)
    cfg = dataclasses.replace(cfg, episode_s=episode_s, imitate=dataclasses.replace(cfg.imitate, **imitate))
    return ShapeBatch(cfg, SEEDS), [ImitateEnv(cfg, seed) for seed in SEEDS]


@pytest.mark.parametrize("preset, imitate", [("lower_biped", {}), ("quadruped", {}), ("fish", {"max_root_deviation": 0.1}),
                                             ("manta", {})])
def test_batch_steps_as_its_single_environments(preset: str, imitate: dict) -> None:
    """Random shapes, random actions (small for environment 0, so it reaches the horizon; one
    NaN), ends by falls (the fish's off its course, held tight), by the horizon and by early
    resets (with and without a seed): observations, rewards, ends and infos all equal."""
    batch, singles = _pair(preset, episode_s=1.0, **imitate)
    rng = np.random.default_rng(0)
    n = len(singles)
    for i, env in enumerate(singles):
        params = env.space.uniform(rng, 1)[0]
        np.testing.assert_array_equal(batch.reset_one(i, 100 + i, params), env.reset(100 + i, params)[0])
    ended = {"terminated": 0, "truncated": 0}
    for t in range(240):
        actions = rng.normal(0.0, 1.0, (n, batch.act_dim)) * np.array([[0.05], [0.8], [0.4]])
        if t == 7:
            actions[1, 0] = np.nan
        obs, reward, terminated, truncated, infos = batch.step(actions)
        for i, env in enumerate(singles):
            o, r, term, trunc, info = env.step(actions[i])
            np.testing.assert_array_equal(obs[i], o, err_msg=f"step {t} env {i}")
            assert (reward[i], terminated[i], truncated[i]) == (r, term, trunc), f"step {t} env {i}"
            assert infos[i] == info, f"step {t} env {i}"
            if term or trunc or (i == 2 and t % 71 == 70):
                ended["terminated"] += term
                ended["truncated"] += trunc
                seed = None if t % 2 else int(rng.integers(1000))
                params = env.space.uniform(rng, 1)[0]
                np.testing.assert_array_equal(batch.reset_one(i, seed, params), env.reset(seed, params)[0])
    assert ended["truncated"] > 0
    if preset != "manta":
        assert ended["terminated"] > 0


def test_a_diverged_environment_ends_alone_as_its_single_environment_does() -> None:
    batch, singles = _pair("lower_biped", episode_s=30.0)
    for i, env in enumerate(singles):
        batch.reset_one(i, i, env.space.default_array)
        env.reset(i, env.space.default_array)
    for env in (batch.envs[1], singles[1]):
        env.data.qvel[:] = 1e12
    actions = np.zeros((len(singles), batch.act_dim))
    obs, reward, terminated, truncated, infos = batch.step(actions)
    for i, env in enumerate(singles):
        o, r, term, trunc, info = env.step(actions[i])
        np.testing.assert_array_equal(obs[i], o)
        assert (reward[i], terminated[i], truncated[i], infos[i]) == (r, term, trunc, info)
    assert infos[1]["diverged"] and terminated[1] and not infos[0]["diverged"]


def test_the_shape_tasks_make_a_shape_batch() -> None:
    batch = make_batch_env(shape_task("fish"), [1, 2])
    assert isinstance(batch, ShapeBatch) and batch.n == 2 and batch.drain_segments() == []
