"""A vary-shape reference made frame by frame as the scheduler reads it (`common.motion.lazy_retarget`)
is the reference made whole (`retarget.retarget_frames`, then the floor lift), bit for bit,
whatever order its frames are read in; what the per-frame path cannot do exactly (another
root-height rule, a looping clip, a body clearance, no contact) is made whole."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from common.motion.lazy_retarget import FrameRetarget, LazyRetargetedMotion, fits
from common.motion.retarget import ContactPhases, RetargetConfig
from common.tasks.executor.env import ExecutorEnv
from learner.presets import PRESETS

CLIPS = ("humanoid/bandai/dataset-1_walk-left_angry_001", "humanoid3d_walk", "humanoid3d_backflip")
SHAPES = (np.array([1.4, 0.7]), np.array([0.8, 1.3]), np.array([1.0, 1.0]), np.array([1.5, 0.5]))


@pytest.fixture(scope="module")
def env() -> ExecutorEnv:
    cfg = PRESETS["executor-shape"][1].task
    return ExecutorEnv(dataclasses.replace(cfg, executor=dataclasses.replace(cfg.executor, clips=CLIPS)), seed=0)


@pytest.mark.parametrize("clip", CLIPS)
def test_frames_made_on_demand_are_those_made_whole_bit_for_bit(env, clip):
    refs, rng = env._references, np.random.default_rng(7)
    for shape in SHAPES:
        body = env._bodies.get(shape)
        whole = refs.build_eager(clip, body)
        lazy = refs._build(clip, body)
        assert isinstance(lazy, LazyRetargetedMotion) and not lazy.retarget.done.any()
        # scattered schedule windows, as resets at random starts read them (qpos and velocities)
        for start in rng.uniform(0.0, whole.duration_s, 4):
            times = start + np.arange(-12, 40) / 60.0
            assert np.array_equal(lazy.qpos(times), whole.qpos(times))
            assert np.array_equal(lazy.qvel_at(times, 1 / 60.0), whole.qvel_at(times, 1 / 60.0))
        assert 0 < lazy.retarget.done.sum()
        assert np.array_equal(lazy.qpos_frames, whole.qpos_frames), (clip, shape)
        assert lazy.retarget.done.all()


def test_a_reset_makes_only_the_frames_its_schedule_reads(env):
    clip = CLIPS[0]  # a 5 s take
    env._references._cache.clear()
    env.reset(0, SHAPES[0], clip_id=clip, start_s=2.0)
    motion = env._motion(clip)
    made = motion.retarget.done
    assert isinstance(motion, LazyRetargetedMotion) and 0 < made.sum() < 0.4 * len(made)
    fps = motion.frames.fps
    assert not made[: int(1.5 * fps)].any() and made[int(2.0 * fps)]
    for _ in range(10):
        env.step(np.zeros(env.act_dim))
    assert np.array_equal(motion.qpos_frames, env._references.build_eager(clip, env.body).qpos_frames)


def test_what_the_per_frame_path_cannot_do_exactly_is_made_whole(env):
    flags = np.zeros((5, 2), dtype=bool)
    flags[2, 0] = True
    some = ContactPhases(("a", "b"), flags, 0.0)
    none = ContactPhases(("a", "b"), np.zeros((5, 2), dtype=bool), 0.0)
    assert fits(RetargetConfig(), False, some)
    assert not fits(RetargetConfig(root_height="foot_tracks"), False, some)
    assert not fits(RetargetConfig(root_height="contact_smooth"), False, some)
    assert not fits(RetargetConfig(body_clearance_m=0.01), False, some)
    assert not fits(RetargetConfig(), True, some)
    assert not fits(RetargetConfig(), False, none)
    with pytest.raises(ValueError, match="contact_set"):
        FrameRetarget(np.zeros((5, env.nq)), 120.0, env.ref_model, ("a", "b"), 1.0, none, RetargetConfig(), True,
                      env.ref_data)
    refs = env._references
    eager = dataclasses.replace(RetargetConfig(), root_height="foot_tracks")
    old, refs.retarget = refs.retarget, eager
    try:
        motion = refs._build(CLIPS[1], env._bodies.get(SHAPES[1]))
        assert not isinstance(motion, LazyRetargetedMotion)
    finally:
        refs.retarget = old
