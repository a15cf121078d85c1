"""The executor task (UniCon 2020, METHOD.md B): reward terms and termination on hand-made
states, the observation's invariance to where the character stands and faces, reactive state
initialization within its bounds, torque actuation, schedulers, and clip splits."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest

from common.tasks.executor import rewards as rw
from common.tasks.base import TaskConfig
from common.tasks.body_config import BodyConfig
from common.tasks.executor.env import ExecutorEnv, effort_factors, executor_clips, humanoid_clips
from common.tasks.executor.config import ExecutorConfig
from common.tasks.executor.observations import BodyKin, agent_features, observation, target_root_pose
from common.tasks.observations import heading, yaw_matrix
from common.tasks.registry import make_env

CFG = TaskConfig(name="executor", control_hz=60.0, sim_hz=240.0, episode_s=5.0,
                 body=BodyConfig(parameterization="height_thickness", vary_shape=False), executor=ExecutorConfig())


def cfg_with(**changes) -> TaskConfig:
    return dataclasses.replace(CFG, executor=dataclasses.replace(CFG.executor, **changes))


@pytest.fixture(scope="module")
def env() -> ExecutorEnv:
    return make_env(CFG, seed=0)


# ---- reward terms and termination on hand-made states ----

def test_each_term_by_hand():
    # COM 0.3 m off: exp(-10 * 0.09)
    assert rw.com_error([0, 0, 1.0], [0.3, 0, 1.0]) == pytest.approx(0.09)
    # root turned 0.5 rad about z: angle^2 = 0.25
    q = [math.cos(0.25), 0, 0, math.sin(0.25)]
    assert rw.root_rotation_error(q, [1, 0, 0, 0]) == pytest.approx(0.25)
    # 14 bodies, each 0.1 m off: (4 / 14) * 14 * 0.01 = 0.04
    assert rw.joint_position_error(np.full((14, 3), 0.0) + [0.1, 0, 0], np.zeros((14, 3))) == pytest.approx(0.04)
    # one ball joint turned 0.2 rad, one hinge 0.3 rad off: 0.04 + 0.09
    ball = np.array([[math.cos(0.1), math.sin(0.1), 0, 0]])
    assert rw.joint_rotation_error(ball, np.array([[1.0, 0, 0, 0]]), [0.3], [0.0]) == pytest.approx(0.13)
    assert rw.joint_velocity_error([1.0, 2.0], [0.0, 0.0]) == pytest.approx(5.0)
    errors = {"root_position": 0.09, "root_rotation": 0.25, "joint_position": 0.04, "joint_rotation": 0.13, "joint_velocity": 5.0}
    terms = rw.reward_terms(errors, (10.0, 2.0, 40.0, 2.0, 0.1))
    expected = {"root_position": math.exp(-0.9), "root_rotation": math.exp(-0.5), "joint_position": math.exp(-1.6),
                "joint_rotation": math.exp(-0.26), "joint_velocity": math.exp(-0.5)}
    assert terms == pytest.approx(expected)
    w = (0.2, 0.2, 0.1, 0.4, 0.1)
    assert rw.weighted_sum(terms, w) == pytest.approx(sum(wi * expected[t] for wi, t in zip(w, rw.TERMS)))
    assert rw.weighted_sum({t: 1.0 for t in rw.TERMS}, w) == pytest.approx(1.0)


def _quat_mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _about(axis: int, angle: float) -> np.ndarray:
    q = np.zeros(4)
    q[0], q[1 + axis] = math.cos(angle / 2), math.sin(angle / 2)
    return q


def _mat(q) -> np.ndarray:
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(q, float))
    return m.reshape(3, 3)


def test_joint_positions_are_compared_yaw_aligned_without_a_heading_singularity():
    """r_pj's comparison (`rw.yaw_aligned`): for upright roots it is the old heading-frame one
    (a yaw drift costs r_pj nothing); with the root pitched 90 degrees (a crawl, a flip's
    flight), where a heading frame flipped on 3 degrees of pitch, 3 degrees cost what they cost
    upright."""
    rng = np.random.default_rng(0)
    body = rng.normal(0, 0.4, (14, 3))  # a pose: body offsets in the root's frame

    def offsets(q):
        return body @ _mat(q).T  # world-frame offsets of the pose under root rotation q

    def heading_frame_error(q, q_ref):  # the old r_pj: each in its own heading frame
        rel = [offsets(x) @ yaw_matrix(heading(_mat(x))) for x in (q, q_ref)]
        return rw.joint_position_error(*rel)

    def aligned_error(q, q_ref):
        return rw.joint_position_error(rw.yaw_aligned(offsets(q), q, q_ref), offsets(q_ref))

    ref = _quat_mul(_about(2, 0.7), _about(0, 0.1))  # upright, heading 0.7 rad, a little roll
    drifted = _quat_mul(_about(2, 0.35), ref)  # the same pose turned 20 degrees about the vertical
    tilted = _quat_mul(ref, _about(1, math.radians(3)))
    assert aligned_error(drifted, ref) == pytest.approx(0.0, abs=1e-12)
    assert aligned_error(tilted, ref) == pytest.approx(heading_frame_error(tilted, ref), rel=0.05)
    pitched = _quat_mul(_about(2, 0.7), _about(1, math.pi / 2))  # forward axis straight down
    pitched_off = _quat_mul(pitched, _about(1, math.radians(3)))
    upright_cost = aligned_error(tilted, ref)
    assert aligned_error(pitched_off, pitched) == pytest.approx(upright_cost, rel=0.5)
    assert heading_frame_error(pitched_off, pitched) > 20 * upright_cost  # the old frame's flip
    batch = rw.yaw_aligned(np.stack([offsets(drifted), offsets(pitched_off)]), np.stack([drifted, pitched_off]),
                           np.stack([ref, pitched]))
    assert np.array_equal(batch[1], rw.yaw_aligned(offsets(pitched_off), pitched_off, pitched))


def test_termination_rules():
    w = (0.2, 0.2, 0.1, 0.4, 0.1)
    good = {t: 0.9 for t in rw.TERMS}
    one_bad = dict(good, joint_velocity=0.05)
    assert rw.termination(good, w, "per_term", 0.1) is None
    assert rw.termination(one_bad, w, "per_term", 0.1) == "joint_velocity"
    # the weighted sum of one_bad is 0.815: the sum rule (the ablation) lets it go on
    assert rw.termination(one_bad, w, "sum", 0.1) is None
    assert rw.termination({t: 0.05 for t in rw.TERMS}, w, "sum", 0.1) == "sum"
    assert rw.termination({t: 0.0 for t in rw.TERMS}, w, "none", 0.1) is None
    with pytest.raises(ValueError, match="termination rule 'x'"):
        rw.termination(good, w, "x", 0.1)
    # the presets' rule watches the four pose terms: a joint-velocity drop ends nothing, a pose drop does
    assert rw.termination(one_bad, w, "per_term", 0.1, rw.POSE_TERMS) is None
    assert rw.termination(dict(one_bad, joint_rotation=0.05), w, "per_term", 0.1, rw.POSE_TERMS) == "joint_rotation"


# ---- the observation ----

def random_kin(rng, n=15) -> BodyKin:
    rot = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(n)])
    rot *= np.sign(np.linalg.det(rot))[:, None, None]
    return BodyKin(rng.normal(size=(n, 3)), rot, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=3))


def moved(kin: BodyKin, yaw: float, shift: np.ndarray) -> BodyKin:
    r = yaw_matrix(yaw)
    return BodyKin(kin.pos @ r.T + shift, np.einsum("ij,bjk->bik", r, kin.rot), kin.lin @ r.T, kin.ang @ r.T, kin.com @ r.T + shift)


def test_observation_unchanged_under_rigid_translation_and_yaw():
    rng = np.random.default_rng(1)
    actual, target = random_kin(rng), random_kin(rng)
    params = np.array([1.0, 1.2])
    base = observation(actual, [target], params)
    for yaw, shift in [(0.7, np.array([3.0, -2.0, 0.0])), (-2.5, np.array([-10.0, 4.0, 0.0]))]:
        again = observation(moved(actual, yaw, shift), [moved(target, yaw, shift)], params)
        np.testing.assert_allclose(again, base, atol=1e-5)
    # a negative control: moving only the target changes y(X~; X)
    assert not np.allclose(target_root_pose(actual, moved(target, 0.7, np.zeros(3))), target_root_pose(actual, target))
    # and the root height is observed (a vertical move is not invisible)
    assert agent_features(moved(actual, 0.0, np.array([0, 0, 0.5])))[0] == pytest.approx(actual.pos[0, 2] + 0.5)


def test_env_observation_layout(env):
    tau2 = make_env(cfg_with(tau=2), seed=0)
    per_frame = (env.obs_dim - env.space.dim) // 2 - 4  # o(X) + (o + y) with y of 9 numbers
    assert env.space.dim + per_frame + (per_frame + 9) == env.obs_dim
    assert tau2.obs_dim == env.obs_dim + per_frame + 9
    assert env.act_dim == 28


def rigid(qpos: np.ndarray, yaw: float, shift: np.ndarray) -> np.ndarray:
    out = qpos.copy()
    out[0:3] = yaw_matrix(yaw) @ qpos[0:3] + shift
    mujoco.mju_mulQuat(out[3:7], np.array([math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)]), qpos[3:7].copy())
    return out


def test_env_observation_invariant_to_where_the_episode_starts():
    """The character and its schedule moved and turned together observe exactly the same."""
    env = make_env(cfg_with(reactive_init=False), seed=0)
    clip = env.scheduler.clip_ids[0]
    obs_a, _ = env.reset(0, env.space.default_array, clip, 0.3)
    qpos, qvel, start = env.data.qpos.copy(), env.data.qvel.copy(), env.scheduler.frame(0).qpos.copy()
    for yaw, shift in [(1.1, np.array([2.0, -1.0, 0.0])), (-2.9, np.array([-7.0, 5.0, 0.0]))]:
        env.scheduler.begin(env.rng, clip, env.scheduler.t0, align_to=rigid(start, yaw, shift))
        env.data.qpos[:] = rigid(qpos, yaw, shift)
        env.data.qvel[:] = qvel
        env.data.qvel[0:3] = yaw_matrix(yaw) @ qvel[0:3]
        obs_b = env.observe_now()
        np.testing.assert_allclose(obs_b, obs_a, atol=1e-5)
    # negative control: moving the character alone changes the observation
    env.data.qpos[:] = rigid(qpos, 0.0, np.array([0.5, 0.0, 0.0]))
    assert not np.allclose(env.observe_now(), obs_a, atol=1e-3)


# ---- reactive state initialization ----

def test_reactive_initialization_within_bounds():
    env = make_env(cfg_with(rsis_frames=(5, 10), rsis_translation_m=0.1), seed=0)
    offsets = []
    for seed in range(30):
        _, info = env.reset(seed, env.space.default_array)
        offsets.append(info["rsis_offset"])
        assert 5 <= abs(info["rsis_offset"]) <= 10
        assert env.grace == 30
    assert min(offsets) < 0 < max(offsets)
    # without it: the character starts on the tracked frame (up to the floor lift)
    plain = make_env(cfg_with(reactive_init=False, catch_up_steps=0), seed=0)
    _, info = plain.reset(0, plain.space.default_array)
    assert info["rsis_offset"] == 0 and plain.grace == 0
    frame = plain.scheduler.frame(0)
    np.testing.assert_allclose(plain.data.qpos[3:], frame.qpos[3:], atol=1e-12)
    np.testing.assert_allclose(plain.data.qpos[0:2], frame.qpos[0:2], atol=1e-12)
    np.testing.assert_allclose(plain.data.qvel, frame.qvel, atol=1e-12)


def test_a_share_of_starts_on_the_tracked_frame_without_the_wait():
    """`on_frame_share`: that share of starts begins on the tracked frame exactly with the rule
    from the first step; the others are reactive starts with the wait. With share 0 the episode's
    random draws are those of a config without the field (same clip, frame and offset)."""
    env = make_env(cfg_with(on_frame_share=0.5), seed=0)
    on = 0
    for seed in range(40):
        _, info = env.reset(seed, env.space.default_array)
        if info["on_frame"]:
            on += 1
            assert info["rsis_offset"] == 0 and env.grace == 0
            frame = env.scheduler.frame(0)
            np.testing.assert_allclose(env.data.qpos[3:], frame.qpos[3:], atol=1e-12)
            np.testing.assert_allclose(env.data.qvel, frame.qvel, atol=1e-12)
        else:
            assert 5 <= abs(info["rsis_offset"]) <= 10 and env.grace == 30
    assert 10 <= on <= 30
    every = make_env(cfg_with(on_frame_share=1.0), seed=0)
    assert all(every.reset(seed, every.space.default_array)[1]["on_frame"] for seed in range(10))
    a, b = make_env(cfg_with(on_frame_share=0.0), seed=0), make_env(CFG, seed=0)
    for seed in range(5):
        ia, ib = a.reset(seed, a.space.default_array)[1], b.reset(seed, b.space.default_array)[1]
        assert not ia["on_frame"] and ia == ib
        np.testing.assert_array_equal(a.data.qvel, b.data.qvel)
    with pytest.raises(ValueError, match="on-frame-share"):
        cfg_with(on_frame_share=1.5).executor.validate()


def test_reactive_translation_noise_is_bounded():
    env = make_env(cfg_with(rsis_frames=(0, 0), rsis_velocity_std=0.0, rsis_translation_m=0.1), seed=0)
    for seed in range(20):
        env.reset(seed, env.space.default_array)
        frame = env.scheduler.frame(0)
        assert np.linalg.norm(env.data.qpos[0:2] - frame.qpos[0:2]) <= 0.1 + 1e-12


# ---- actuation, episodes ----

def test_torque_actuation_applies_effort_times_action(env):
    env.reset(0, env.space.default_array)
    a = np.zeros(env.act_dim)
    a[0] = 0.5
    env.data.ctrl[:] = a
    mujoco.mj_forward(env.model, env.data)
    assert env.data.actuator_force[0] == pytest.approx(0.5 * env.efforts[0])
    assert np.allclose(env.data.actuator_force[1:], 0.0)
    efforts = effort_factors(env.model, 45.0)
    assert efforts.min() == pytest.approx(100.0 * 45 / 70) and efforts.max() == pytest.approx(600.0 * 45 / 70)


def test_episode_ends_by_a_term_and_truncates_at_clip_end():
    env = make_env(cfg_with(reactive_init=False, at_clip_end="stop", termination="none"), seed=0)
    clip = env.scheduler.clip_ids[0]
    env.reset(0, env.space.default_array, clip, None)
    steps_left = env.scheduler.status()["steps_left"]
    for k in range(steps_left + 5):
        _, r, term, trunc, info = env.step(np.zeros(env.act_dim))
        assert np.isfinite(r) and 0.0 <= r <= 1.0 + 1e-9
        if term or trunc:
            break
    assert trunc and not term and k + 1 == steps_left
    # per-term termination: a ragdoll (zero torque) loses some term within a second
    env = make_env(cfg_with(reactive_init=False, catch_up_steps=0), seed=0)
    env.reset(0, env.space.default_array)
    for _ in range(60):
        _, _, term, trunc, info = env.step(np.zeros(env.act_dim))
        if term:
            break
    assert term and info["ended_by"] in rw.TERMS and info["terms"][info["ended_by"]] < 0.1


def test_random_torques_do_not_diverge():
    env = make_env(cfg_with(termination="none"), seed=0)
    rng = np.random.default_rng(0)
    for seed in range(4):
        env.reset(seed, env.space.default_array)
        for _ in range(120):
            _, _, term, trunc, info = env.step(rng.normal(0.0, 0.37, env.act_dim))
            assert not info["diverged"]
            if trunc:
                break


def test_pd_variant_tracks_better_than_a_ragdoll():
    """PD targets on the reference with zero actions keep all terms up longer than zero torque."""
    lengths = {}
    for actuation in ("pd", "torque"):
        env = make_env(cfg_with(actuation=actuation, reactive_init=False, catch_up_steps=0), seed=0)
        total = 0
        for seed in range(4):
            env.reset(seed, env.space.default_array)
            for k in range(120):
                _, _, term, trunc, _ = env.step(np.zeros(env.act_dim))
                if term or trunc:
                    break
            total += k + 1
        lengths[actuation] = total
    assert lengths["pd"] > lengths["torque"]


def test_pd_velocity_target_applies_no_force_on_the_target_state():
    """Placed exactly on a moving target frame (its joint angles and velocities), the PD with the
    switch applies no force at all; without it (DeepMimic's PD) it brakes every moving joint by
    kd qdot~. Checks the lead's DOF order against MuJoCo's own actuator lengths and velocities."""
    forces = {}
    for on in (False, True):
        env = make_env(cfg_with(actuation="pd", pd_velocity_target=on, reactive_init=False, clips=("humanoid3d_dance_a",)), seed=0)
        env.reset(0, env.space.default_array, start_s=0.3)
        frame = env.scheduler.frame(1)
        m, d = env.model, env.data
        d.qpos[: env.nq], d.qvel[: env.nv] = frame.qpos, frame.qvel
        d.ctrl[:] = env.pd_target(frame)
        assert np.all((d.ctrl > m.actuator_ctrlrange[:, 0]) & (d.ctrl < m.actuator_ctrlrange[:, 1]))
        mujoco.mj_forward(m, d)
        forces[on] = d.actuator_force.copy()
        kd = -m.actuator_biasprm[:, 2]
    np.testing.assert_allclose(forces[True], 0.0, atol=1e-9)
    np.testing.assert_allclose(forces[False], np.clip(-kd * frame.qvel[6:], -m.actuator_forcerange[:, 1],
                                                      m.actuator_forcerange[:, 1]), atol=1e-9)
    assert np.abs(forces[False]).max() > 100.0  # the dance moves: DeepMimic's PD brakes it hard


def test_pd_velocity_target_tracks_a_fast_clip_longer():
    """The humanoid's PD alone on the dance from the tracked frame: with the target velocity its
    joint-rotation term stays higher after 8 control steps (without it the shoulder lags 0.6 rad)."""
    term = {}
    for on in (False, True):
        env = make_env(cfg_with(actuation="pd", pd_velocity_target=on, reactive_init=False, termination="none",
                                clips=("humanoid3d_dance_a",)), seed=0)
        env.reset(0, env.space.default_array, start_s=0.3)
        for _ in range(8):
            _, _, _, _, info = env.step(np.zeros(env.act_dim))
        term[on] = info["terms"]["joint_rotation"]
    assert term[True] > 2 * term[False]


def test_joint_velocity_term_instant_or_over_the_control_step():
    """`joint_velocity = "step_mean"` compares the control step's mean joint velocity (the angle
    change over the step, quaternion-aware) with the frame's; "instant" the simulator's qvel at the
    step's end. Checked by hand on one PD step of the dance, where the two differ."""
    terms = {}
    for measure in ("instant", "step_mean"):
        env = make_env(cfg_with(actuation="pd", reactive_init=False, termination="none", joint_velocity=measure,
                                clips=("humanoid3d_dance_a",)), seed=0)
        env.reset(0, env.space.default_array, start_s=0.3)
        before = env.qpos.copy()
        _, _, _, _, info = env.step(np.zeros(env.act_dim))
        mean = np.empty(env.nv)
        mujoco.mj_differentiatePos(env.ref_model, mean, env.dt, before, env.qpos)
        qdot = mean if measure == "step_mean" else env.data.qvel[: env.nv]
        ref = env.scheduler.frame(0).qvel[6:]
        expected = math.exp(-CFG.executor.reward_scales[4] * float(np.sum((qdot[6:] - ref) ** 2)))
        assert info["terms"]["joint_velocity"] == pytest.approx(expected, rel=1e-9)
        terms[measure] = info["terms"]["joint_velocity"]
    assert terms["instant"] != pytest.approx(terms["step_mean"], rel=1e-3)


def test_ankle_and_arm_armature_set_their_joints_and_still_the_chatter():
    """`ankle_armature` is the rotor inertia of the two ankles' six DOF and of nothing else
    (`arm_armature`: the shoulders' and elbows' eight); with
    0.1 kg m^2 the PD alone on the dance (its feet leave the floor) keeps the ankles' joint
    velocities near the clip's, where with the builder's 0.01 the clamped force makes them flip
    from substep to substep (`ExecutorConfig.ankle_armature`)."""
    err = {}
    for armature in (0.01, 0.1):
        env = make_env(cfg_with(actuation="pd", pd_velocity_target=True, reactive_init=False, termination="none",
                                ankle_armature=armature, clips=("humanoid3d_dance_a",)), seed=0)
        m = env.model
        ankle = np.array(["ankle" in m.joint(int(m.dof_jntid[d])).name for d in range(m.nv)])
        assert ankle.sum() == 6 and np.all(m.dof_armature[ankle] == armature)
        assert np.all(m.dof_armature[6 : env.nv][~ankle[6 : env.nv]] == 0.01)
        env.reset(0, env.space.default_array, start_s=0.3)
        sq = []
        for _ in range(20):
            env.step(np.zeros(env.act_dim))
            sq.append(np.sum((env.data.qvel[ankle] - env.scheduler.frame(0).qvel[np.flatnonzero(ankle)]) ** 2))
        err[armature] = float(np.mean(sq))
    assert err[0.1] < 0.1 * err[0.01]  # measured: 0.3 against 140 (rad/s)^2
    m = make_env(cfg_with(actuation="pd", arm_armature=0.2), seed=0).model
    arm = np.array([m.joint(int(m.dof_jntid[d])).name.split("_")[-1] in ("shoulder", "elbow") for d in range(m.nv)])
    assert arm.sum() == 8 and np.all(m.dof_armature[arm] == 0.2) and np.all(m.dof_armature[6:][~arm[6:]] == 0.01)


# ---- clips, split, scheduler ----

def test_train_and_test_splits_are_disjoint_and_cover_the_library():
    train = dict(executor_clips(cfg_with(split="train")))
    test = dict(executor_clips(cfg_with(split="test")))
    every = dict(humanoid_clips())
    assert not set(train) & set(test) and set(train) | set(test) == set(every)
    assert len(test) >= 1 and len(train) > len(test)
    uniform = executor_clips(cfg_with(split="train", clip_draws="uniform"))
    assert {label for _, label in uniform} == {"root/all"}


def test_unknown_clip_is_a_clear_error():
    with pytest.raises(ValueError, match="do not play on the humanoid"):
        executor_clips(cfg_with(clips=("nope",)))
    env = make_env(CFG, seed=0)
    with pytest.raises(ValueError, match="not in this scheduler's set"):
        env.reset(0, env.space.default_array, "mass/walk")


def test_target_velocity_window_differences_the_clip_over_that_many_steps():
    """`target_velocity_window = w`: the target frames' velocities are the clip's differences over
    +-w control steps (checked against `CharacterMotion.qvel_at`); a wider window is smoother on
    a fast clip (smaller frame-to-frame changes); 0 or 31 steps are refused by name."""
    jumps = {}
    for w in (1, 3):
        env = make_env(cfg_with(reactive_init=False, target_velocity_window=w, clips=("humanoid3d_run",)), seed=0)
        env.reset(0, env.space.default_array, start_s=0.2)
        s = env.scheduler
        t = s.t0 + np.arange(4) * env.dt
        want = env._motion("humanoid3d_run").qvel_at(t, w * env.dt)
        got = np.array([s.frame(i).qvel for i in range(4)])
        np.testing.assert_allclose(got[:, 6:], want[:, 6:], atol=1e-9)
        jumps[w] = float(np.abs(np.diff(got[:, 6:], axis=0)).mean())
    assert jumps[3] < jumps[1]
    from common.tasks.executor.schedulers.factory import make_scheduler

    assert make_scheduler("dataset", env).velocity_window == 3  # `morphmimic play` plays as the task trained
    for bad in (0, 31):
        with pytest.raises(ValueError, match="target_velocity_window|target-velocity-window"):
            cfg_with(target_velocity_window=bad).validate()


def test_dataset_scheduler_reschedules_at_the_clip_end(env):
    env.reset(0, env.space.default_array)
    s = env.scheduler
    n = s.status()["steps_left"]
    before = s.reschedules
    qpos = env.qpos.copy()
    for _ in range(n):
        jumped = s.advance(env.rng, qpos)
    assert jumped and s.reschedules == before + 1
    # the new clip starts under the character: same horizontal position
    np.testing.assert_allclose(s.frame(0).qpos[0:2], qpos[0:2], atol=1e-9)


def test_clip_segments_end_tracked_at_a_reschedule_and_not_at_a_termination():
    """`drain_segments` (adaptive clip sampling): a start near a clip's end reaches it inside the
    wait, a tracked segment; the next clip's ragdoll then breaks a term, an untracked one."""
    env = make_env(cfg_with(reactive_init=False, catch_up_steps=20, actuation="torque"), seed=0)
    env.reset(0, env.space.default_array, clip_id="humanoid3d_walk")
    first = env.scheduler.clip_id
    duration = env.scheduler.status()["clip_duration_s"]
    env.reset(0, env.space.default_array, clip_id=first, start_s=duration - 5 * env.dt)
    assert env.drain_segments() == []  # a reset before anything ended counts nothing
    for _ in range(200):
        _, _, term, trunc, info = env.step(np.zeros(env.act_dim))
        if term or trunc:
            break
    assert term
    segments = env.drain_segments()
    assert segments[0] == (first, True, duration), segments  # a tracked segment ends at its clip's end
    failed = env.scheduler.status()
    assert segments[-1] == (failed["clip_id"], False, pytest.approx(failed["clip_time_s"])), segments
    assert 0 < segments[-1][2] <= failed["clip_duration_s"]  # where it failed, inside the clip (time bins)
    assert all(tracked for _, tracked, _ in segments[:-1])
    assert env.drain_segments() == []


def test_config_rejects_bad_values():
    for bad in (dict(tau=0), dict(alpha=1.5), dict(effort_scale=0.0), dict(speed=0.0), dict(rsis_frames=(5, 2)),
                dict(passive_damping=-1.0), dict(catch_up_steps=-1), dict(ankle_armature=-0.1), dict(terminate_on=()),
                dict(terminate_on=("joint_speed",)), dict(terminate_on=("root_position", "root_position"))):
        with pytest.raises(ValueError, match="--task.executor"):
            ExecutorConfig(**bad)


def test_projectiles_start_parked_and_hit_the_character():
    from common.tasks.executor.env import PROJECTILES

    env = make_env(cfg_with(projectile=True, reactive_init=False, termination="none", actuation="pd"), seed=0)
    plain = make_env(cfg_with(reactive_init=False, termination="none", actuation="pd"), seed=0)
    env.reset(0, env.space.default_array, env.scheduler.clip_ids[0], 0.2)
    plain.reset(0, plain.space.default_array, plain.scheduler.clip_ids[0], 0.2)
    np.testing.assert_allclose(env.qpos, plain.qpos, atol=1e-12)  # parked balls touch nothing
    char_bodies = set(range(1, env.ref_model.nbody))
    hit = False
    for k in range(40):
        if k % 2 == 0:
            env.throw_projectile(10.0, 2.0)
        env.step(np.zeros(env.act_dim))
        for c in env.data.contact[: env.data.ncon]:
            b = {int(env.model.geom_bodyid[c.geom1]), int(env.model.geom_bodyid[c.geom2])}
            hit |= bool(b & set(env.balls)) and bool(b & char_bodies)
    assert hit
    assert env._next_ball == 20 % PROJECTILES
    with pytest.raises(ValueError, match="no projectile"):
        plain.throw_projectile()


def test_termination_waits_for_the_catch_up_steps():
    """A ragdoll breaks a term at once, but the episode is ended only after the grace."""
    env = make_env(cfg_with(reactive_init=False, catch_up_steps=12), seed=0)
    env.reset(0, env.space.default_array)
    for k in range(1, 60):
        _, _, term, trunc, info = env.step(np.zeros(env.act_dim))
        if k <= 12:
            assert not term
        if term:
            break
    assert term and k > 12


def test_on_track_ends_the_wait_once_every_watched_term_is_above_alpha():
    """From the tracked frame exactly every pose term starts above alpha: with "on_track" the
    wait ends on the first step, so a ragdoll's episode ends as soon as a watched term breaks,
    long before the 30 steps after which the default wait lets the rule act."""
    ends = {}
    for mode in ("after_steps", "on_track"):
        env = make_env(cfg_with(reactive_init=False, catch_up_steps=30, catch_up_ends=mode,
                                terminate_on=rw.POSE_TERMS), seed=0)
        env.reset(0, env.space.default_array)
        for k in range(1, 120):
            _, _, term, trunc, info = env.step(np.zeros(env.act_dim))
            if k == 1:
                assert min(info["terms"][t] for t in rw.POSE_TERMS) >= 0.1  # on track at the start
            if term or trunc:
                break
        assert term
        ends[mode] = k
    assert ends["after_steps"] > 30
    assert ends["on_track"] < 30


def test_on_track_keeps_the_wait_while_a_term_is_below_alpha():
    """A start a metre off the tracked frame's root breaks the root-position term at once: the
    wait then still holds the rule back, as with "after_steps", until the 30 steps are over."""
    env = make_env(cfg_with(reactive_init=False, catch_up_steps=30, catch_up_ends="on_track"), seed=0)
    env.reset(0, env.space.default_array)
    env.data.qpos[0] += 1.0
    for k in range(1, 120):
        _, _, term, trunc, info = env.step(np.zeros(env.act_dim))
        if k <= 30:
            assert info["terms"]["root_position"] < 0.1 and not term and env.grace == 30
        if term or trunc:
            break
    assert term and k == 31


def test_the_watched_terms_decide_what_ends_an_episode():
    """The same zero-torque start under both watch sets: with all five terms the episode ends
    on the first term below alpha; with the pose terms only it never ends on joint_velocity."""
    ends = {}
    for watch in (rw.TERMS, rw.POSE_TERMS):
        env = make_env(cfg_with(reactive_init=False, catch_up_steps=0, terminate_on=watch), seed=0)
        env.reset(0, env.space.default_array)
        for k in range(1, 120):
            _, _, term, trunc, info = env.step(np.zeros(env.act_dim))
            if term or trunc:
                break
        assert term
        ends[watch] = (k, info["ended_by"])
        assert info["ended_by"] in watch
        assert min(info["terms"][t] for t in watch) < 0.1
    assert ends[rw.POSE_TERMS][1] != "joint_velocity"
    assert ends[rw.POSE_TERMS][0] >= ends[rw.TERMS][0]


@pytest.mark.parametrize("factor", [0.75, 1.25])
def test_a_lighter_or_heavier_body_scores_the_same_pose_the_same(factor: float):
    """scale_mass (the robustness table's mass rows) changes the body, not the reward: on the
    first step from the tracked frame, with the projectile bodies in the scene, every term is
    as without it to within what the lighter body's first step moves."""
    cfg = cfg_with(projectile=True, reactive_init=False, termination="none", actuation="pd")
    terms = []
    for f in (1.0, factor):
        env = make_env(cfg, seed=0)
        env.scale_mass(f)
        env.reset(0, env.space.default_array, "humanoid3d_walk", 0.3)
        _, _, _, _, info = env.step(np.zeros(env.act_dim))
        terms.append(info["terms"])
    # NOTE: before the masses' derived fields were recomputed, root_position read 0.03-0.3 here
    for name, value in terms[0].items():
        assert terms[1][name] == pytest.approx(value, abs=0.03), name


def test_mirror_images_join_their_sources_side_of_the_split():
    from common.tasks.executor.env import labelled_clips

    plain, mirrored = labelled_clips(CFG), labelled_clips(cfg_with(mirror=True))
    assert mirrored == [p for c, label in plain for p in ((c, label), (c + "~mirror", label))]
    held_out = labelled_clips(cfg_with(mirror=True, split="test"))
    assert {c.removesuffix("~mirror") for c, _ in held_out}.isdisjoint({c for c, _ in plain})
    assert len(held_out) == 2 * len(labelled_clips(cfg_with(split="test")))
    assert [c for c, _ in labelled_clips(cfg_with(clips=("humanoid3d_walk~mirror",)))] == ["humanoid3d_walk~mirror"]
    env = make_env(cfg_with(mirror=True, clips=("humanoid3d_kick",), reactive_init=False), seed=0)
    assert list(env.scheduler.clip_ids) == ["humanoid3d_kick", "humanoid3d_kick~mirror"]
    env.reset(0, env.space.default_array, "humanoid3d_kick~mirror", 0.5)
    assert env.scheduler.status()["clip_id"] == "humanoid3d_kick~mirror"
    with pytest.raises(ValueError, match="do not play on the humanoid"):
        labelled_clips(cfg_with(clips=("humanoid3d_walk~flipped",)))


def test_action_rate_penalty_and_previous_action_in_the_observation():
    """The reward is the weighted terms less w x the mean squared change of the applied action
    (a_-1 = 0 after a start, actions clipped to +-3 for PD targets), and the observation ends with
    the action just applied; without the switches the observation is as before."""
    w = 0.25
    plain = make_env(cfg_with(actuation="pd", reactive_init=False), seed=0)
    env = make_env(cfg_with(actuation="pd", reactive_init=False, action_rate_weight=w, previous_action_obs=True), seed=0)
    assert env.obs_dim == plain.obs_dim + env.act_dim
    clip = env.scheduler.clip_ids[0]
    obs, _ = env.reset(0, env.space.default_array, clip, 0.0)
    assert np.array_equal(obs[-env.act_dim:], np.zeros(env.act_dim))
    plain.reset(0, plain.space.default_array, clip, 0.0)
    rng = np.random.default_rng(0)
    previous = np.zeros(env.act_dim)
    for _ in range(3):
        action = rng.normal(0.0, 0.02, env.act_dim)
        action[0] = 7.0  # applied as 3.0
        obs, r, term, *_ = env.step(action)
        obs_plain, r_plain, *_ = plain.step(action)
        applied = np.clip(action, -3.0, 3.0)
        assert np.array_equal(obs[: plain.obs_dim], obs_plain)
        assert np.allclose(obs[-env.act_dim:], applied.astype(np.float32))
        assert r == pytest.approx(r_plain - w * np.mean((applied - previous) ** 2), abs=1e-12)
        previous = applied
        assert not term
    lo, hi = rw.reward_range(env.ex.reward_weights, w, "pd")
    assert lo == -w * 36.0 and hi == pytest.approx(1.0)
    assert rw.action_rate_penalties(np.array([[1.0, -1.0]]), np.array([[0.0, 1.0]]), 0.5)[0] == 0.5 * (1 + 4) / 2


def test_preview_observes_the_frames_at_its_offsets():
    """With `preview` 1 2 4 the observation holds the blocks of tau = 4's observation at those
    offsets (the same state and frames), and a bad preview is refused naming the value."""
    four = make_env(cfg_with(tau=4, reactive_init=False), seed=0)
    preview = make_env(cfg_with(preview=(1, 2, 4), reactive_init=False), seed=0)
    clip = four.scheduler.clip_ids[0]
    block = (four.obs_dim - preview.obs_dim)  # one block: tau 4 has four, the preview three
    head = four.obs_dim - 4 * block
    for env in (four, preview):
        env.reset(0, env.space.default_array, clip, 0.2)
    for _ in range(3):
        a, b = four.step(np.zeros(four.act_dim))[0], preview.step(np.zeros(preview.act_dim))[0]
        blocks = a[head:].reshape(4, block)
        assert np.array_equal(b[:head], a[:head])
        assert np.array_equal(b[head:].reshape(3, block), blocks[[0, 1, 3]])
    for bad in [(2, 3), (1, 1), (1, 3, 2), (1, 61)]:
        with pytest.raises(ValueError, match="preview"):
            cfg_with(preview=bad)
