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
    frame, _ = env._body_frame()
    assert obs[-3:] == pytest.approx(frame.T @ env.course_offset() / env.length_m, abs=1e-6)
    # the root moved sideways and up off the course by known amounts: the observation says so
    v = env.rot[:2, :2] @ env.v0
    side = np.array([-v[1], v[0], 0.0]) / np.linalg.norm(v)
    env.data.qpos[0:3] = env.ref_q[0][0:3] + 0.2 * side + np.array([0.0, 0.0, 0.1]) + 0.5 * np.array([v[0], v[1], 0.0])
    offset = frame @ env._obs()[-3:] * env.length_m  # back to the world
    assert offset == pytest.approx(0.2 * side + np.array([0.0, 0.0, 0.1]), abs=1e-5)  # along the course: not part of it
    assert env.off_course_m() == pytest.approx(np.hypot(0.2, 0.1), abs=1e-6)


def test_only_a_swimmer_observes_a_course() -> None:
    walker = PRESETS["lower_biped"][1].task
    with pytest.raises(ValueError, match="'lower_biped' is not a swimmer; only a swimmer has a course"):
        task_check(dataclasses.replace(walker, imitate=dataclasses.replace(walker.imitate, observe_course=True)))
