"""Reward terms against hand computations (Won & Lee 2019, METHOD.md A)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.tasks.shape import rewards


def test_mean_sq_divides_by_dimension() -> None:
    assert rewards.mean_sq(np.array([3.0, 4.0])) == pytest.approx(25.0 / 2)
    assert rewards.bell(0.1, 0.2) == pytest.approx(math.exp(-0.5))


def test_pose_error_uses_so3_angle_for_ball_joints() -> None:
    half = 0.3 / 2  # a 0.3 rad rotation about z
    q = np.array([[1.0, 0.0, 0.0, 0.0]])
    q_ref = np.array([[math.cos(half), 0.0, 0.0, math.sin(half)]])
    # one ball joint off by 0.3 rad, one hinge off by 0.1 rad: mean of squares over 2 joints
    err = rewards.pose_error(q, q_ref, np.array([0.5]), np.array([0.4]))
    assert err == pytest.approx((0.3**2 + 0.1**2) / 2)
    # the antipodal quaternion is the same rotation
    assert rewards.pose_error(q, -q, np.zeros(0), np.zeros(0)) == pytest.approx(0.0, abs=1e-12)


def test_end_effector_error_sums_over_effectors() -> None:
    ee = np.zeros((2, 3))
    ref = np.array([[0.3, 0.0, 0.0], [0.0, 0.0, 0.6]])
    assert rewards.end_effector_error(ee, ref) == pytest.approx((0.09 + 0.36) / 3)


def test_weighted_terms_match_the_table() -> None:
    w, s = rewards.WEIGHTS["lower_biped"], rewards.SENSITIVITIES
    assert w == (5.0, 2.0, 2.0, 1.0, 1.0, 1.0) and s == (0.02, 0.5, 0.2, 0.2, 0.05, 0.1)
    errors = {"pose": 0.02, "velocity": 0.0, "end_effector": 0.4, "com_velocity": 0.2, "direction": 0.0, "torque": 0.1}
    terms = rewards.reward_terms(w, s, errors)
    assert terms["pose"] == pytest.approx(5.0 * math.exp(-1.0))
    assert terms["velocity"] == pytest.approx(2.0)
    assert terms["end_effector"] == pytest.approx(2.0 * math.exp(-2.0))
    assert terms["torque"] == pytest.approx(math.exp(-1.0))
    imit, task, reg = rewards.split(terms)
    assert imit == pytest.approx(5 * math.exp(-1) + 2 + 2 * math.exp(-2))
    assert task == pytest.approx(math.exp(-1) + 1.0)
    assert reg == pytest.approx(math.exp(-1))


def test_normalization_reconstruction() -> None:
    """v_target = v0 (lbar/lbar0) max(0.5, 1 - sigma_l/lbar); direction error / that factor;
    torque error times m0/m."""
    norm = rewards.Normalization.from_legs(np.array([0.8, 1.2]), np.array([1.0, 1.0]), mass_kg=100.0, base_mass_kg=50.0)
    assert norm.leg_ratio == pytest.approx(1.0)
    assert norm.asym == pytest.approx(1.0 - 0.2 / 1.0)
    assert norm.mass_ratio == pytest.approx(0.5)
    assert norm.target_speed(1.5) == pytest.approx(1.5 * 0.8)
    d, d_t = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    assert rewards.direction_error(d, d_t, norm) == pytest.approx(1.0 / 0.8)
    assert rewards.direction_error(d, d_t, None) == pytest.approx(1.0)
    tau, limit = np.array([100.0, 0.0]), np.array([200.0, 100.0])
    assert rewards.torque_error(tau, limit, norm) == pytest.approx(0.125 * 0.5)
    assert rewards.torque_error(tau, limit, None) == pytest.approx(0.125)
    very_asym = rewards.Normalization.from_legs(np.array([0.1, 1.9]), np.array([1.0, 1.0]), 1.0, 1.0)
    assert very_asym.asym == 0.5
