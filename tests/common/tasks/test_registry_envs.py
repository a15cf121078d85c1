"""Every registered task resets and steps with zero and random actions without NaN, and keeps
the Env contract (parametrized over the registry, like mujoco_playground's test)."""

from __future__ import annotations

import numpy as np
import pytest

from common.tasks.base import TaskConfig
from common.tasks.body_config import BodyConfig
from common.tasks.shape.config import ImitateConfig
from common.tasks.registry import TASKS, make_env, task_clips, task_space

SHAPE_TASKS = [name for name in TASKS if name != "reach"]


def _cfg(name: str) -> TaskConfig:
    if name == "reach":
        return TaskConfig(name=name)
    if name == "executor":
        return TaskConfig(name=name, control_hz=60.0, sim_hz=240.0, episode_s=5.0, 
                          body=BodyConfig(parameterization="height_thickness", vary_shape=False))
    return TaskConfig(name=name, control_hz=30.0, sim_hz=480.0, episode_s=30.0,
                      imitate=ImitateConfig(max_root_deviation=1.0))


@pytest.mark.parametrize("name", sorted(TASKS))
@pytest.mark.parametrize("policy", ["zero", "random"])
def test_reset_and_step_without_nan(name: str, policy: str) -> None:
    cfg = _cfg(name)
    env = make_env(cfg, seed=0)
    rng = np.random.default_rng(1)
    assert env.space == task_space(cfg)
    assert isinstance(task_clips(cfg), list)
    params = env.space.uniform(rng, 1)[0]
    obs, info = env.reset(3, params)
    assert obs.shape == (env.obs_dim,) and obs.dtype == np.float32 and np.isfinite(obs).all()
    for _ in range(40):
        action = np.zeros(env.act_dim) if policy == "zero" else rng.normal(0.0, 1.0, env.act_dim)
        obs, r, term, trunc, info = env.step(action)
        assert obs.shape == (env.obs_dim,) and np.isfinite(obs).all() and np.isfinite(r)
        assert not info.get("diverged")
        assert not (term and trunc), "an episode ends either by termination or by truncation"
        if term or trunc:
            obs, _ = env.reset(None, env.space.uniform(rng, 1)[0])


@pytest.mark.parametrize("name", SHAPE_TASKS)
def test_shape_parameters_lead_the_observation(name: str) -> None:
    """s_b (the sampled parameter vector) is the first part of the state (METHOD.md A)."""
    env = make_env(_cfg(name), seed=0)
    params = env.space.uniform(np.random.default_rng(5), 1)[0]
    obs, _ = env.reset(0, params)
    np.testing.assert_allclose(obs[: env.space.dim], params, rtol=1e-6)
    assert env.act_dim == env.model.nu


def test_out_of_range_shape_is_refused() -> None:
    env = make_env(_cfg("lower_biped"), seed=0)
    bad = env.space.default_array.copy()
    bad[0] = 3.0
    with pytest.raises(ValueError, match="global_x"):
        env.reset(0, bad)


@pytest.mark.parametrize("name", sorted(TASKS))
def test_a_divergence_terminates_with_zero_reward_and_observation(name: str) -> None:
    """Every task ends a diverged episode the one way (`base.diverged_step`): terminated, not
    truncated, reward 0, a zero observation."""
    env = make_env(_cfg(name), seed=0)
    env.reset(0, env.space.default_array)
    env.data.qvel[:] = 1e11  # above mjMAXVAL: MuJoCo warns (mjWARN_BADQVEL) and resets the state
    obs, r, term, trunc, info = env.step(np.zeros(env.act_dim))
    assert info["diverged"] and not info["fell"]
    assert term and not trunc and r == 0.0
    assert obs.shape == (env.obs_dim,) and not obs.any()
