"""Reward terms of Won & Lee 2019 (METHOD.md A, "Reward" and "Reward normalization") as pure
numpy functions: no MuJoCo, no state, so each is checked against a hand computation.

Every term is a bell `w * exp(-err / sigma)` where `||x||^2` is the squared L2 norm divided by
the dimension of x (METHOD.md A). R = R_imit + R_task + R_reg:
- R_imit = w1 bell(joint angle error, s1) + w2 bell(joint velocity error, s2) + w3 bell(end-effector error, s3)
- R_task = w4 bell(COM velocity error, s4) + w5 bell(facing direction error, s5)
- R_reg  = w6 bell(torque, s6)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.motion.quat import quat_angle

SENSITIVITIES = (0.02, 0.5, 0.2, 0.2, 0.05, 0.1)
"""s1..s6 for every character (Won & Lee 2019, METHOD.md A)."""
WEIGHTS = {
    "biped": (4.0, 1.0, 2.0, 1.0, 2.0, 1.0),
    "humanoid": (4.0, 1.0, 2.0, 1.0, 2.0, 1.0),
    "lower_biped": (5.0, 2.0, 2.0, 1.0, 1.0, 1.0),
    "quadruped": (5.0, 2.0, 2.0, 1.0, 1.0, 1.0),
    "fish": (3.0, 2.0, 4.0, 1.0, 0.5, 0.5),
    "manta": (3.0, 2.0, 4.0, 1.0, 0.5, 0.5),
}
"""w1..w6 per character (Won & Lee 2019 table, METHOD.md A)."""
TERMS = ("pose", "velocity", "end_effector", "com_velocity", "direction", "torque")


def bell(err: float, sigma: float) -> float:
    """exp(-err / sigma), the kernel of every term."""
    return float(np.exp(-err / sigma))


def mean_sq(x: np.ndarray) -> float:
    """||x||^2 in the paper's sense: squared L2 norm divided by the dimension of x."""
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    return float(x @ x / max(1, x.size))


@dataclass(frozen=True)
class Normalization:
    """Won & Lee 2019 reward normalization (METHOD.md A; all three rules are a reconstruction).

    leg_ratio = lbar / lbar0 (mean leg length over the base character's); asym = max(0.5,
    1 - sigma_l / lbar) with sigma_l the standard deviation of the leg lengths; mass_ratio =
    m0 / m (base mass over this body's). Swimmers and legless bodies use their length ratio
    for leg_ratio and asym = 1. speed_factor: a swimmer's fitted stroke speed over that
    (`learner.tools.stroke_fit`, `--task.imitate.swimmer-speed stroke_fit`), else 1.
    """

    leg_ratio: float = 1.0
    asym: float = 1.0
    mass_ratio: float = 1.0
    speed_factor: float = 1.0

    @staticmethod
    def from_legs(leg_lengths_m: np.ndarray, base_leg_lengths_m: np.ndarray, mass_kg: float, base_mass_kg: float) -> "Normalization":
        legs = np.asarray(leg_lengths_m, dtype=np.float64)
        lbar = float(legs.mean())
        lbar0 = float(np.mean(base_leg_lengths_m))
        return Normalization(lbar / lbar0, max(0.5, 1.0 - float(legs.std()) / lbar), base_mass_kg / mass_kg)

    def target_speed(self, v0_m_s: float) -> float:
        """v_target = v0 (lbar / lbar0) max(0.5, 1 - sigma_l / lbar) (reconstruction), times
        `speed_factor`."""
        return v0_m_s * self.leg_ratio * self.asym * self.speed_factor


def pose_error(q_ball: np.ndarray, q_ball_ref: np.ndarray, q_hinge: np.ndarray, q_hinge_ref: np.ndarray) -> float:
    """||q - q_ref||^2: mean over joints of the squared joint difference (rad^2), on SO(3) for
    ball joints (`[B, 4]` quaternions, the root orientation may be one of them) and Euclidean
    for hinges (`[H]` angles)."""
    ang = np.concatenate([quat_angle(q_ball, q_ball_ref).reshape(-1), (np.asarray(q_hinge) - q_hinge_ref).reshape(-1)])
    return mean_sq(ang)


def end_effector_error(ee: np.ndarray, ee_ref: np.ndarray) -> float:
    """sum_i ||e_i - e_ref_i||^2 with each squared norm divided by 3 (`[E, 3]` m, root-relative)."""
    d = np.asarray(ee, dtype=np.float64) - ee_ref
    return float(np.sum(d * d) / 3.0)


def direction_error(d: np.ndarray, d_target: np.ndarray, norm: Normalization | None) -> float:
    """||d - d_target||^2 of horizontal unit facing vectors `[2]`, divided by
    max(0.5, 1 - sigma_l / lbar) with normalization (reconstruction)."""
    err = mean_sq(np.asarray(d) - d_target)
    return err / norm.asym if norm is not None else err


def torque_error(tau: np.ndarray, tau_scale: np.ndarray, norm: Normalization | None) -> float:
    """sum_i ||tau_i||^2 made dimensionless: torques `[nu]` N m divided by the base character's
    torque limits `tau_scale` `[nu]`, mean of squares (so the 0.1 sensitivity means something
    for a 50 kg biped and a 7 kg fish alike), times m0 / m with normalization (reconstruction)."""
    err = mean_sq(np.asarray(tau) / tau_scale)
    return err * norm.mass_ratio if norm is not None else err


def reward_terms(weights, sigmas, errors: dict[str, float]) -> dict[str, float]:
    """Weighted bells `w_k exp(-err_k / s_k)` for the six TERMS (missing errors count as 0 reward)."""
    return {name: (w * bell(errors[name], s) if name in errors else 0.0) for name, w, s in zip(TERMS, weights, sigmas)}


def split(terms: dict[str, float]) -> tuple[float, float, float]:
    """(R_imit, R_task, R_reg) of `reward_terms` output."""
    return (terms["pose"] + terms["velocity"] + terms["end_effector"], terms["com_velocity"] + terms["direction"], terms["torque"])
