"""The executor over body shapes (`--task.body.vary-shape`, the `executor-shape` preset, issue 55
item 1): each reset builds the body of its shape and retargets the clip onto it (stance feet on
the floor), both cached in bounded LRUs; the observation carries the shape; bad shapes are one
clear error; the position terms are normalized by the body's size (1 on the base shape)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from common.motion.root_height import foot_heights
from common.tasks.executor import rewards as rw
from common.tasks.executor.config import ExecutorConfig
from common.tasks.executor.env import ExecutorEnv
from common.tasks.registry import task_space
from learner.presets import PRESETS

WALK = "humanoid3d_walk"
CLIPS = (WALK, "humanoid3d_run")
TALL, SHORT = np.array([1.4, 0.7]), np.array([0.8, 1.3])
STANCE_TOLERANCE_M = 0.01
"""The retargeting's leg solve stops within 5 mm (`RetargetConfig.ik_tolerance_m`)."""


def shape_task(**executor):
    """`executor-shape` on two short clips (and any executor changes)."""
    cfg = PRESETS["executor-shape"][1].task
    return dataclasses.replace(cfg, executor=dataclasses.replace(cfg.executor, clips=CLIPS, **executor))


@pytest.fixture(scope="module")
def env() -> ExecutorEnv:
    return ExecutorEnv(shape_task(), seed=0)


def test_the_preset_is_executor_track_over_the_shape_box():
    track, shape = PRESETS["executor-track"][1], PRESETS["executor-shape"][1]
    assert shape.task.body.vary_shape and not track.task.body.vary_shape
    as_track = dataclasses.replace(shape, name=track.name, task=dataclasses.replace(shape.task, body=track.task.body),
                                   sampler=track.sampler)
    assert as_track == track
    # item 2: shape and class drawn together, with a Vm worth sampling from; nothing else of the sampler
    assert shape.sampler.shape_by_class and not track.sampler.shape_by_class
    assert shape.sampler == dataclasses.replace(track.sampler, shape_by_class=True, k=5.0, p_mcmc=20, vm_fit_steps=64)
    assert not any(cfg.sampler.shape_by_class for name, (_, cfg) in PRESETS.items() if name != "executor-shape")
    space = task_space(shape.task)
    assert space.names == ("height", "thickness") and space.low == (0.75, 0.5) and space.high == (1.5, 1.5)
    pinned = task_space(track.task)
    assert pinned.low == pinned.high == pinned.default == (1.0, 1.0)


def test_two_shapes_get_their_own_models_and_references_with_the_stance_feet_on_the_floor(env):
    got = {}
    for name, shape in (("tall", TALL), ("short", SHORT)):
        env.reset(0, shape, clip_id=WALK, start_s=0.0)
        motion = env._motion(WALK)
        h, _ = foot_heights(env.ref_model, motion.qpos_frames, tuple(env.base_character.foot_geoms))
        stance = env._references.contacts(WALK).flags
        assert 0.3 < stance.mean() < 0.9  # real contact phases: the check has something to check
        assert np.abs(h[stance]).max() < STANCE_TOLERANCE_M, (name, np.abs(h[stance]).max())
        assert h.min() > -STANCE_TOLERANCE_M  # no foot digs in, stance or swing
        got[name] = (env.model, env.ref_model, motion, env.character.mass_kg, env.leg_ratio)
    tall_model, tall_ref, tall_motion, tall_kg, tall_ratio = got["tall"]
    short_model, short_ref, short_motion, short_kg, short_ratio = got["short"]
    assert tall_model is not short_model and tall_ref is not short_ref
    assert tall_kg != short_kg and tall_ratio > 1.0 > short_ratio
    # root height follows leg length (the walk's stride too: its path is scaled about its first frame)
    qt, qs = tall_motion.qpos_frames, short_motion.qpos_frames
    assert qt.shape == qs.shape
    assert np.mean(qt[:, 2]) / np.mean(qs[:, 2]) == pytest.approx(tall_ratio / short_ratio, rel=0.05)
    stride = np.linalg.norm(qt[-1, :2] - qt[0, :2]) / np.linalg.norm(qs[-1, :2] - qs[0, :2])
    assert stride == pytest.approx(tall_ratio / short_ratio, rel=1e-9)
    # the joint angles carry over (away from the leg solve: the arms)
    arm = env.character.qpos_slices["right_shoulder"]
    np.testing.assert_allclose(qt[:, arm], qs[:, arm], atol=1e-12)


def test_the_observation_starts_with_the_episodes_shape(env):
    for shape in (TALL, SHORT, np.array([1.5, 0.5])):
        obs, _ = env.reset(3, shape, clip_id=WALK)
        np.testing.assert_array_equal(obs[:2], shape.astype(np.float32))
        obs, *_ = env.step(np.zeros(env.act_dim))
        np.testing.assert_array_equal(obs[:2], shape.astype(np.float32))


def test_the_clip_shape_cache_hits_and_stays_bounded():
    env = ExecutorEnv(shape_task(reference_cache=2, shape_cache=2), seed=0)
    env.reset(0, TALL, clip_id=WALK)
    tall_walk, tall_body = env._motion(WALK), env.body
    env.reset(0, TALL, clip_id=WALK)
    assert env._motion(WALK) is tall_walk and env.body is tall_body  # a hit: the same tables, no rebuild
    for shape in (SHORT, np.array([1.1, 1.1]), np.array([0.9, 0.9])):
        for clip in CLIPS:
            env.reset(0, shape, clip_id=clip)
            assert len(env._references) <= 2 and len(env._bodies) <= 2
    env.reset(0, TALL, clip_id=WALK)  # evicted long ago: built again, the same frames
    assert env._motion(WALK) is not tall_walk
    np.testing.assert_array_equal(env._motion(WALK).qpos_frames, tall_walk.qpos_frames)


@pytest.mark.parametrize("params, says", [
    (np.array([1.0, 1.0, 1.0]), r"expected 2 values for \['height', 'thickness'\], got 3: \[1.0, 1.0, 1.0\]; "
                                r"allowed: height in \[0.75, 1.5\], thickness in \[0.5, 1.5\]"),
    (np.array([2.0, 1.0]), r"parameter 'height' = 2 is out of range; allowed: height in \[0.75, 1.5\]"),
    (np.array([1.0, np.nan]), r"parameter 'thickness' = nan is not a finite number; allowed: thickness in \[0.5, 1.5\]"),
])
def test_a_bad_shape_is_one_clear_error(env, params, says):
    with pytest.raises(ValueError, match=says):
        env.reset(0, params, clip_id=WALK)


def test_position_terms_are_normalized_by_size_and_not_on_the_base_shape(env):
    errors = np.random.default_rng(0).uniform(0.0, 0.3, (3, 5))
    out = rw.size_normalized_errors(errors, np.array([1.0, 2.0, 0.5]))
    assert np.array_equal(out[0], errors[0])  # the base shape: bit for bit
    np.testing.assert_array_equal(out[1:, [1, 3, 4]], errors[1:, [1, 3, 4]])  # rotations, velocities unchanged
    np.testing.assert_allclose(out[1:, [0, 2]], errors[1:, [0, 2]] / np.array([[4.0], [0.25]]))
    env.reset(0, env.space.default_array, clip_id=WALK)
    assert env.leg_ratio == 1.0
    env.reset(0, TALL, clip_id=WALK)
    assert env.leg_ratio == env.body.norm.leg_ratio > 1.0
    off = ExecutorEnv(shape_task(reward_normalization=False), seed=0)
    off.reset(0, TALL, clip_id=WALK)
    assert off.leg_ratio == 1.0


def test_a_scaled_mass_stays_on_every_body():
    env = ExecutorEnv(shape_task(), seed=0)
    env.scale_mass(1.25)
    for shape in (TALL, SHORT, TALL):
        env.reset(0, shape, clip_id=WALK)
        assert env.model.body_mass.sum() == pytest.approx(1.25 * env.body.body_mass.sum())


def test_cache_sizes_are_checked():
    for bad in (dict(reference_cache=0), dict(shape_cache=0), dict(shape_cache=10**6)):
        with pytest.raises(ValueError, match=f"--task.executor.{next(iter(bad)).replace('_', '-')} = "):
            ExecutorConfig(**bad)
