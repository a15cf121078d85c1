"""UniCon's five reward terms and its constrained termination rule (METHOD.md B "Reward";
Wang et al. 2020, eqs. 5-6), as pure numpy functions checked against hand computations.

    r = 0.2 r_pr + 0.2 r_qr + 0.1 r_pj + 0.4 r_qj + 0.1 r_wj,   each r_i = exp(-k_i err_i)

- r_pr, root position: the centre of mass against the target's, err = ||c - c~||^2 (m^2), k = 10
  (DeepMimic's centre-of-mass term, which UniCon names as its root position term);
- r_qr, root rotation: err = angle(q_r, q~_r)^2 (rad^2), k = 2 (UniCon's own term);
- r_pj, joint positions: every body's position relative to the root in the root's heading
  frame, err = (4 / B) sum_j ||p_j - p~_j||^2 over the B non-root bodies, k = 40. DeepMimic sums
  over its four end effectors with k = 40; UniCon penalizes all joints without giving a scale,
  so the sum is rescaled to four bodies' worth (a reconstruction, `ExecutorConfig.reward_scales`):
  the term falls to 0.1 at an RMS body error of 12 cm whatever the body count;
- r_qj, joint rotations: err = sum_j angle(q_j, q~_j)^2 over ball joints and hinges, k = 2;
- r_wj, joint velocities: err = sum ||qdot_j - qdot~_j||^2 over every non-root DOF, k = 0.1.

Constrained objective (eq. 6, UniCon 4.3): the episode ends as soon as any single term falls
below alpha = 0.1 (`terminated`, rule "per_term"); the ablation ends it only when the weighted
sum does (rule "sum").
"""

from __future__ import annotations

import numpy as np

from common.motion.quat import quat_angle

TERMS = ("root_position", "root_rotation", "joint_position", "joint_rotation", "joint_velocity")
"""The five terms in the order of `ExecutorConfig.reward_weights` / `reward_scales`."""
POSE_TERMS = TERMS[:4]
"""The four pose terms: what the executor presets' per-term rule watches (`ExecutorConfig.terminate_on`)."""
END_EFFECTORS_IN_DEEPMIMIC = 4


def com_error(com: np.ndarray, com_ref: np.ndarray) -> float:
    """||c - c~||^2 (m^2) of the centres of mass `[3]` (world frame)."""
    d = np.asarray(com, dtype=np.float64) - np.asarray(com_ref, dtype=np.float64)
    return float(d @ d)


def root_rotation_error(quat: np.ndarray, quat_ref: np.ndarray) -> float:
    """Squared geodesic angle (rad^2) between root quaternions (w, x, y, z) `[4]`."""
    return float(quat_angle(quat, quat_ref) ** 2)


def joint_position_error(rel_pos: np.ndarray, rel_pos_ref: np.ndarray) -> float:
    """(4 / B) sum_j ||p_j - p~_j||^2 (m^2) of body positions `[B, 3]`, each relative to its own
    character's root and expressed in that root's heading frame (see module docstring)."""
    d = np.asarray(rel_pos, dtype=np.float64) - np.asarray(rel_pos_ref, dtype=np.float64)
    return float(np.sum(d * d) * END_EFFECTORS_IN_DEEPMIMIC / max(1, d.shape[0]))


def joint_rotation_error(balls: np.ndarray, balls_ref: np.ndarray, hinges: np.ndarray, hinges_ref: np.ndarray) -> float:
    """sum_j angle^2 (rad^2) over ball joints (quaternions `[Nb, 4]`) and hinges (angles `[Nh]`)."""
    a = quat_angle(np.asarray(balls).reshape(-1, 4), np.asarray(balls_ref).reshape(-1, 4)) if len(balls) else np.zeros(0)
    h = np.asarray(hinges, dtype=np.float64) - np.asarray(hinges_ref, dtype=np.float64)
    return float(np.sum(a * a) + np.sum(h * h))


def joint_velocity_error(qvel_joints: np.ndarray, qvel_joints_ref: np.ndarray) -> float:
    """sum ||qdot - qdot~||^2 ((rad/s)^2) over the non-root DOF `[nv - 6]`."""
    d = np.asarray(qvel_joints, dtype=np.float64) - np.asarray(qvel_joints_ref, dtype=np.float64)
    return float(d @ d)


def reward_terms(errors: dict[str, float], scales: tuple[float, ...]) -> dict[str, float]:
    """{term: exp(-k err)} for the five terms (unweighted, each in (0, 1])."""
    return {name: float(np.exp(-k * errors[name])) for name, k in zip(TERMS, scales)}


def weighted_sum(terms: dict[str, float], weights: tuple[float, ...]) -> float:
    """r = sum_i w_i r_i (UniCon eq. 5)."""
    return float(sum(w * terms[name] for name, w in zip(TERMS, weights)))


def termination(terms: dict[str, float], weights: tuple[float, ...], rule: str, alpha: float,
                watch: tuple[str, ...] = TERMS) -> str | None:
    """Why the episode ends now, or None: "per_term" ends it at the first term of `watch` below
    alpha (returns that term's name; UniCon watches all five), "sum" when the weighted sum is
    below alpha ("sum"), "none" never."""
    if rule == "per_term":
        for name in watch:
            if terms[name] < alpha:
                return name
        return None
    if rule == "sum":
        return "sum" if weighted_sum(terms, weights) < alpha else None
    if rule == "none":
        return None
    raise ValueError(f"termination rule {rule!r} is not one of per_term, sum, none")
