"""The executor's reference cleaning switches (`ExecutorConfig.reference_filter_hz`,
`reference_floor`, `pd_target_range`): off by default, so a checkpoint trained before them runs
exactly as before; on, the filtered tracks' derivatives are what every consumer of the target
velocities reads."""

from __future__ import annotations

import dataclasses

import numpy as np

from common.motion.clean import FILTER_GRID_HZ, clean_motion, lowest_geom_heights, widen_ranges
from common.motion.reference import CharacterMotion
from common.tasks.base import TaskConfig
from common.tasks.body_config import BodyConfig
from common.tasks.executor.config import ExecutorConfig
from common.tasks.registry import make_env

CLIP = "humanoid3d_backflip"


def cfg_with(**changes) -> TaskConfig:
    ex = ExecutorConfig(clips=(CLIP,), reactive_init=False, **changes)
    return TaskConfig(name="executor", control_hz=60.0, sim_hz=240.0, episode_s=5.0,
                      body=BodyConfig(parameterization="height_thickness", vary_shape=False), executor=ex)


def test_defaults_leave_the_clips_and_the_pd_ranges_as_they_were():
    ex = ExecutorConfig()
    assert (ex.reference_filter_hz, ex.reference_floor, ex.pd_target_range) == (0.0, False, "joint_limits")
    env = make_env(cfg_with(actuation="pd"), seed=0)
    raw = CharacterMotion.from_clip(env.library.clip(CLIP).with_(loop=False), env.ref_model)
    np.testing.assert_array_equal(env._motion(CLIP).qpos_frames, raw.qpos_frames)
    np.testing.assert_array_equal(env.model.actuator_ctrlrange, env.ref_model.actuator_ctrlrange)


def test_a_saved_config_without_the_fields_loads_with_the_defaults():
    from learner.config import _from_dict

    saved = dataclasses.asdict(ExecutorConfig())
    for name in ("reference_filter_hz", "reference_floor", "pd_target_range"):
        saved.pop(name)
    assert _from_dict(ExecutorConfig, saved) == ExecutorConfig()


def test_filtered_references_feed_the_reward_the_observation_and_the_pd_lead():
    env = make_env(cfg_with(actuation="pd", pd_velocity_target=True, reference_filter_hz=7.0, reference_floor=True), seed=0)
    motion = env._motion(CLIP)
    raw = CharacterMotion.from_clip(env.library.clip(CLIP).with_(loop=False), env.ref_model)
    assert motion.frames.fps >= FILTER_GRID_HZ and motion.duration_s == np.float64(raw.duration_s)
    np.testing.assert_allclose(motion.qpos_frames, clean_motion(raw, 7.0, True).qpos_frames)
    assert lowest_geom_heights(env.ref_model, motion.qpos_frames).min() > -1e-9
    env.reset(0, env.space.default_array, clip_id=CLIP, start_s=0.5)
    for _ in range(3):
        env.step(np.zeros(env.act_dim))
    t = env.scheduler.t0 + env.scheduler.k * env.dt
    now, nxt = env.scheduler.frame(0), env.scheduler.frame(1)
    # the target velocities are the cleaned motion's differences (its derivative), the same
    # frames the reward (frame 0), the PD's lead (frame 1) and the observation (their kinematics) read
    want = motion.qvel_at(np.array([t, t + env.dt]), env.dt)
    np.testing.assert_allclose(now.qvel, want[0], atol=1e-9)
    np.testing.assert_allclose(nxt.qvel, want[1], atol=1e-9)
    lead = env.pd_target(nxt) - env.layout.to_vector(nxt.qpos)
    np.testing.assert_allclose(lead, env.pd_lead_s * nxt.qvel[6:], atol=1e-12)
    kin = env.target_kinematics()
    ref = env.reference_kinematics(np.stack([now.qpos, nxt.qpos]), np.stack([now.qvel, nxt.qvel]))
    np.testing.assert_allclose(kin.ang, ref.ang)
    np.testing.assert_allclose(kin.lin, ref.lin)


def test_widened_pd_ranges_only_for_pd_actuation():
    pd = make_env(cfg_with(actuation="pd", pd_target_range="widened"), seed=0)
    np.testing.assert_allclose(pd.model.actuator_ctrlrange, widen_ranges(pd.ref_model))
    assert np.all(pd.model.jnt_range == pd.ref_model.jnt_range)  # the joints' own limits stay
    torque = make_env(cfg_with(actuation="torque", pd_target_range="widened"), seed=0)
    np.testing.assert_array_equal(torque.model.actuator_ctrlrange, np.tile([-1.0, 1.0], (torque.nu, 1)))
