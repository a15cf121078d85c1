"""A swimmer's course in its observation (`--task.imitate.observe-course`, the manta's default):
the last three inputs are the root's offset from the reference's course, the quantity its fall
rule ends episodes on, in the root's heading frame and in body lengths."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from common.tasks.registry import make_env, task_check, task_space
from learner.presets import PRESETS


def _manta(observe: bool):
    task = PRESETS["manta"][1].task
    env = make_env(dataclasses.replace(task, imitate=dataclasses.replace(task.imitate, observe_course=observe)), seed=0)
    obs, _ = env.reset(0, task_space(task).default_array)
    return env, obs


def test_the_course_offset_is_observed_in_body_lengths() -> None:
    env, obs = _manta(True)
    plain, plain_obs = _manta(False)
    assert env.obs_dim == plain.obs_dim + 3 and obs.shape == (env.obs_dim,)
    assert np.allclose(obs[:-3], plain_obs, atol=1e-6)  # the same episode start: only the course is added
    # the root turned 60 degrees left of the course (+x, the clip's direction at heading 0) and
    # moved 0.2 m to its left, 0.1 m up and 0.5 m along it: seen from the root's heading frame the
    # offset is 0.2 m at 30 degrees to its right, 0.1 m up (the part along the course is not part of it)
    assert env.rot[:2, :2] @ env.v0 / np.linalg.norm(env.v0) == pytest.approx([1.0, 0.0], abs=1e-9)
    theta = np.radians(60.0)
    env.data.qpos[3:7] = [np.cos(theta / 2), 0.0, 0.0, np.sin(theta / 2)]
    env.data.qpos[0:3] = env.ref_q[0][0:3] + np.array([0.5, 0.2, 0.1])
    expected = np.array([0.2 * np.sin(theta), 0.2 * np.cos(theta), 0.1]) / env.length_m
    assert env._obs()[-3:] == pytest.approx(expected, abs=1e-6)
    assert env.off_course_m() == pytest.approx(np.hypot(0.2, 0.1), abs=1e-9)


def test_only_a_swimmer_observes_a_course() -> None:
    walker = PRESETS["lower_biped"][1].task
    walker = dataclasses.replace(walker, imitate=dataclasses.replace(walker.imitate, observe_course=True))
    with pytest.raises(ValueError, match="'lower_biped' is not a swimmer; only a swimmer has a course"):
        task_check(walker)  # before a run starts
    with pytest.raises(ValueError, match="'lower_biped' is not a swimmer; only a swimmer has a course"):
        make_env(walker)  # and wherever an environment is built
