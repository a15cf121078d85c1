"""The shape tasks' environment: reward normalization, termination, the reference state start
and shape change during an episode."""

from __future__ import annotations

import dataclasses
import re

import mujoco
import numpy as np
import pytest

from common.tasks.base import TaskConfig
from common.tasks.body_config import BodyConfig
from common.motion.retarget_config import RetargetConfig
from common.tasks.shape.config import ImitateConfig
from common.tasks.observations import heading, quat_to_mat, yaw_matrix
from common.tasks.registry import make_env

CFG = TaskConfig(name="lower_biped", control_hz=30.0, sim_hz=480.0, episode_s=30.0)


def _shape(env, **values) -> np.ndarray:
    return env.space.validate(values)


def test_episode_starts_on_the_reference() -> None:
    env = make_env(CFG, seed=0)
    env.reset(0, env.space.default_array)
    np.testing.assert_allclose(env.data.qpos[7:], env.ref_q[0][7:], atol=1e-9)
    terms = env.reward_terms()
    assert terms["pose"] == pytest.approx(env.weights[0], rel=1e-6)
    assert terms["end_effector"] == pytest.approx(env.weights[2], rel=1e-6)


@pytest.mark.parametrize("normalize", [True, False])
def test_target_velocity_follows_leg_length_only_with_normalization(normalize: bool) -> None:
    env = make_env(dataclasses.replace(CFG, imitate=dataclasses.replace(CFG.imitate, reward_normalization=normalize)), seed=0)
    env.reset(0, _shape(env, global_z=0.6))
    short, norm = np.linalg.norm(env.target_velocity()), env.norm
    assert norm.leg_ratio < 0.8
    env.reset(0, env.space.default_array)
    base = np.linalg.norm(env.target_velocity())
    assert base == pytest.approx(np.linalg.norm(env.v0))
    if normalize:
        assert short == pytest.approx(base * norm.leg_ratio * norm.asym)
    else:
        assert short == pytest.approx(base)


def test_lying_on_the_floor_is_a_fall() -> None:
    env = make_env(CFG, seed=0)
    env.reset(0, env.space.default_array)
    env.data.qpos[2] = 0.1
    env.data.qpos[3:7] = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]  # pitched onto its side
    mujoco.mj_forward(env.model, env.data)
    _, _, terminated, truncated, info = env.step(np.zeros(env.act_dim))
    assert terminated and not truncated and info["fell"]
    assert info["fall_bodies"] == ["FemurR"]  # on its right side: the thigh is on the floor, the feet do not count


def test_standing_on_the_feet_names_no_fall_body() -> None:
    env = make_env(CFG, seed=0)
    env.reset(0, env.space.default_array)
    _, _, terminated, _, info = env.step(np.zeros(env.act_dim))
    assert not terminated and "fall_bodies" not in info and env.fall_bodies() == []


def test_horizon_truncates_without_terminating() -> None:
    cfg = TaskConfig(name="quadruped", control_hz=30.0, sim_hz=480.0, episode_s=0.2)
    env = make_env(cfg, seed=0)
    env.reset(0, env.space.default_array)
    ends = [env.step(np.zeros(env.act_dim))[2:4] for _ in range(cfg.episode_steps)]
    assert ends[-1] == (False, True)
    assert all(e == (False, False) for e in ends[:-1])


@pytest.mark.parametrize("offset, ends", [((0.0, 3.0, 0.0), True), ((0.0, 0.0, -3.0), True), ((-3.0, 0.0, 0.0), False),
                                           ((3.0, 0.5, 0.0), False)])
def test_a_swimmer_off_its_reference_course_terminates_but_not_one_behind_or_ahead(offset, ends) -> None:
    """Sideways or vertically more than a body length off the reference's course is a fall;
    lagging behind or leading along it is not (a body's stroke may be slower or faster than its
    scaled reference), with the reference heading turned 90 degrees so "along" is the world's y."""
    cfg = TaskConfig(name="fish", control_hz=30.0, sim_hz=480.0,
                     imitate=ImitateConfig(max_root_deviation=1.0, task_params=("heading",)))
    env = make_env(cfg, seed=0)
    env.reset(0, np.concatenate([env.space.default_array[:-1], [np.pi / 2]]))
    turned = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # reference x -> world y
    env.data.qpos[0:3] = env.ref_q[0][0:3] + turned @ np.asarray(offset) * env.length_m
    mujoco.mj_forward(env.model, env.data)
    assert env.off_course_m() == pytest.approx(np.linalg.norm(offset[1:]) * env.length_m, rel=1e-9)
    assert env.step(np.zeros(env.act_dim))[2] is ends


def test_a_swimmers_reference_covers_the_distance_its_target_velocity_asks_for() -> None:
    """A short and a long fish: the reference root moves at the target velocity (v0 times the
    body-length ratio), so the task's target and the reference agree on every length (the
    reference used to move at v0 whatever the length)."""
    env = make_env(TaskConfig(name="fish", control_hz=30.0, sim_hz=480.0), seed=0)
    speeds = {}
    for name, shape in (("short", env.space.low_array), ("long", env.space.high_array)):
        env.reset(0, shape)
        cycle = env.motion.duration_s
        q = env._ref_qpos(np.array([0.0, cycle]))
        ref_speed = np.linalg.norm(q[1, :2] - q[0, :2]) / cycle
        speeds[name] = ref_speed
        assert ref_speed == pytest.approx(np.linalg.norm(env.target_velocity()), rel=0.02), name
    assert speeds["long"] > 2.0 * speeds["short"]


def test_pd_gains_follow_the_torque_limits_so_a_small_body_is_not_saturated() -> None:
    """The smallest lower biped gets 1.5% of the base's torque limits. With the base's gains its
    PD sits at the limit on about a quarter of its actuators under zero actions; with the gains
    scaled by the same factor on none of them. The base shape is unchanged either way, and a
    morph keeps the scaling."""
    def saturated(env, shape) -> float:
        env.reset(0, shape)
        at_limit = []
        for _ in range(20):
            env.step(np.zeros(env.act_dim))
            at_limit.append(np.mean(np.abs(env.data.actuator_force) >= 0.999 * env.model.actuator_forcerange[:, 1]))
        return float(np.mean(at_limit))

    fixed = make_env(CFG, seed=0)
    scaled = make_env(dataclasses.replace(CFG, imitate=dataclasses.replace(CFG.imitate, pd_gains_follow_torque=True)), seed=0)
    small = fixed.space.low_array
    assert saturated(fixed, small) > 0.1
    assert saturated(scaled, small) < 0.02
    f = scaled.model.actuator_forcerange[0, 1] / scaled.base.model.actuator_forcerange[0, 1]
    assert f < 0.05
    np.testing.assert_allclose(scaled.model.actuator_gainprm[:, 0], f * scaled.base.model.actuator_gainprm[:, 0])
    np.testing.assert_allclose(scaled.model.dof_armature, f * scaled.base.model.dof_armature)
    scaled.reset(0, scaled.space.default_array)
    np.testing.assert_array_equal(scaled.model.actuator_gainprm, scaled.base.model.actuator_gainprm)
    scaled.set_shape(small)
    np.testing.assert_allclose(scaled.model.actuator_biasprm[:, 1:3], f * scaled.base.model.actuator_biasprm[:, 1:3])


def test_fixed_shape_space_is_the_base_shape() -> None:
    env = make_env(dataclasses.replace(CFG, body=BodyConfig(vary_shape=False)), seed=0)
    np.testing.assert_array_equal(env.space.low_array, env.space.high_array)
    assert env.obs_dim == make_env(CFG, seed=0).obs_dim


def test_shape_box_scale_shrinks_the_box_toward_the_base_shape() -> None:
    from common.tasks.shape.env import ImitateEnv

    full = ImitateEnv.param_space(CFG)
    half = ImitateEnv.param_space(dataclasses.replace(CFG, body=BodyConfig(shape_box_scale=0.5)))
    d = full.default_array
    np.testing.assert_allclose(half.low_array, d + 0.5 * (full.low_array - d))
    np.testing.assert_allclose(half.high_array, d + 0.5 * (full.high_array - d))
    np.testing.assert_array_equal(half.default_array, d)
    with pytest.raises(ValueError, match=r"--task.body.shape-box-scale = 1.5 is not allowed: give a finite number in \(0, 1\]"):
        BodyConfig(shape_box_scale=1.5)


def test_an_unknown_root_height_rule_is_refused_by_its_flag() -> None:
    with pytest.raises(ValueError, match=re.escape("--task.imitate.retarget.root-height = 'stilts': give contact_set, foot_tracks, contact_smooth")):
        ImitateConfig(retarget=RetargetConfig(root_height="stilts"))


def test_task_parameters_rotate_and_speed_up_the_reference() -> None:
    cfg = dataclasses.replace(CFG, imitate=dataclasses.replace(CFG.imitate, task_params=("speed", "heading")))
    env = make_env(cfg, seed=0)
    assert env.space.names[-2:] == ("speed", "heading")
    params = env.space.default_array.copy()
    params[-2:] = [1.2, np.pi / 2]
    env.reset(0, params)
    v = env.target_velocity()
    assert abs(v[0]) < 0.1 * abs(v[1]) and np.linalg.norm(v) == pytest.approx(1.2 * np.linalg.norm(env.v0))


def test_set_shape_keeps_the_state_and_updates_the_observation() -> None:
    env = make_env(CFG, seed=0)
    env.reset(0, env.space.default_array)
    for _ in range(3):
        env.step(np.zeros(env.act_dim))
    qvel, k = env.data.qvel.copy(), env.k
    new = _shape(env, global_z=1.2)
    env.set_shape(new)
    np.testing.assert_allclose(env.data.qvel, qvel)
    assert env.k == k
    obs, *_ = env.step(np.zeros(env.act_dim))
    np.testing.assert_allclose(obs[: env.space.dim], new, rtol=1e-6)
    assert env.character.height_m > 1.1 * make_env(CFG, seed=0).character.height_m


def test_current_com_velocity_in_the_observation_is_measured() -> None:
    """The state's current COM velocity (METHOD.md A, s_s) matches the COM moved along qvel by
    a tiny time step (it once read zero: mj_step does not compute it)."""
    env = make_env(TaskConfig(name="lower_biped"), seed=0)
    env.reset(0, env.space.default_array)
    for _ in range(6):
        obs, *_ = env.step(np.zeros(env.act_dim))
    frame = yaw_matrix(heading(quat_to_mat(env.data.qpos[3:7])))
    com_vel_obs = obs[-5:-2]
    h = 1e-6
    data = mujoco.MjData(env.model)
    data.qpos[:] = env.data.qpos
    mujoco.mj_forward(env.model, data)
    before = data.subtree_com[env.root_body].copy()
    mujoco.mj_integratePos(env.model, data.qpos, env.data.qvel, h)
    mujoco.mj_forward(env.model, data)
    finite_diff = frame.T @ ((data.subtree_com[env.root_body] - before) / h)
    assert np.linalg.norm(com_vel_obs) > 0.1
    np.testing.assert_allclose(com_vel_obs, finite_diff, atol=0.05 * np.linalg.norm(finite_diff) + 1e-3)


def test_rotation_vectors_match_scipy() -> None:
    from scipy.spatial.transform import Rotation

    from common.tasks.observations import quat_to_rotvec

    q = np.random.default_rng(0).normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[0] = (1.0, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(quat_to_rotvec(q), Rotation.from_quat(q, scalar_first=True).as_rotvec(), atol=1e-12)


def test_the_papers_fall_rule_counts_the_quadrupeds_shins() -> None:
    """With shins allowed on the floor (`shin_contact_is_fall=False`), the task's fall comes no
    earlier than Won & Lee's (any body but the feet), which `info["fell_paper_rule"]` reports,
    and in some episodes later: a shin touched first. A short, wide body under random actions
    (on the base shape the trunk or a thigh lands first)."""
    cfg = TaskConfig(name="quadruped", control_hz=30.0, sim_hz=480.0, episode_s=10.0,
                     imitate=ImitateConfig(shin_contact_is_fall=False))
    env = make_env(cfg, seed=0)
    shape = env.space.default_array.copy()
    for name, value in (("global_x", 1.5), ("global_y", 1.5), ("global_z", 0.5)):
        shape[list(env.space.names).index(name)] = value
    earlier = 0
    for seed in range(3):
        env.reset(seed, shape)
        rng = np.random.default_rng(seed)
        paper_at = None
        for k in range(300):
            _, _, term, trunc, info = env.step(rng.normal(0.0, 1.0, env.act_dim))
            if info["fell_paper_rule"] and paper_at is None:
                paper_at = k
            if term or trunc:
                break
        assert not term or (paper_at is not None and paper_at <= k)
        earlier += paper_at is not None and (paper_at < k or not term)
    assert earlier >= 1
