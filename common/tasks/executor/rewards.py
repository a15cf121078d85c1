"""UniCon's five reward terms and its constrained termination rule (METHOD.md B "Reward";
Wang et al. 2020, eqs. 5-6), as pure numpy functions checked against hand computations.

    r = 0.2 r_pr + 0.2 r_qr + 0.1 r_pj + 0.4 r_qj + 0.1 r_wj,   each r_i = exp(-k_i err_i)

- r_pr, root position: the centre of mass against the target's, err = ||c - c~||^2 (m^2), k = 10
  (DeepMimic's centre-of-mass term, which UniCon names as its root position term);
- r_qr, root rotation: err = angle(q_r, q~_r)^2 (rad^2), k = 2 (UniCon's own term);
- r_pj, joint positions: every body's position relative to its own root, the character's turned
  about the vertical by the yaw between the two roots (`yaw_aligned`: what a heading frame
  removes, without one), err = (4 / B) sum_j ||p_j - p~_j||^2 over the B non-root bodies, k = 40. DeepMimic sums
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

import functools

import numpy as np

from common.motion.quat import quat_angle

TERMS = ("root_position", "root_rotation", "joint_position", "joint_rotation", "joint_velocity")
"""The five terms in the order of `ExecutorConfig.reward_weights` / `reward_scales`."""
POSE_TERMS = TERMS[:4]
"""The four pose terms: what the executor presets' per-term rule watches (`ExecutorConfig.terminate_on`)."""
END_EFFECTORS_IN_DEEPMIMIC = 4


def _square_each(x: np.ndarray) -> np.ndarray:
    """x ** 2 of each element as a numpy scalar squares it (libm's pow), which differs from the
    array square (x * x) in the last bit for about one value in a thousand."""
    x = np.asarray(x, dtype=np.float64)
    # NOTE: Python floats' ** is the same libm pow as numpy scalars', without a numpy scalar per element
    return np.array([v ** 2 for v in x.reshape(-1).tolist()]).reshape(x.shape)


def _contiguous(x) -> np.ndarray:
    """x as a C-ordered float64 array. NOTE: numpy sums the last axis of a C-ordered array row
    by row (each row as a 1-D sum, pairwise), but of another layout (a fancy-indexed batch is
    one) column by column, which rounds differently: every sum here reads C-ordered arrays so a
    batch's rows equal the states' own sums bit for bit."""
    return np.ascontiguousarray(x, dtype=np.float64)


def com_errors(com: np.ndarray, com_ref: np.ndarray) -> np.ndarray:
    """||c - c~||^2 (m^2) of centres of mass `[..., 3]` (world frame) -> `[...]`."""
    d = _contiguous(com) - _contiguous(com_ref)
    return (d[..., None, :] @ d[..., :, None])[..., 0, 0]


def root_rotation_errors(quat: np.ndarray, quat_ref: np.ndarray) -> np.ndarray:
    """Squared geodesic angles (rad^2) between root quaternions (w, x, y, z) `[..., 4]` -> `[...]`."""
    return _square_each(quat_angle(_contiguous(quat), _contiguous(quat_ref)))


def yaw_aligned(offsets: np.ndarray, quat: np.ndarray, quat_ref: np.ndarray) -> np.ndarray:
    """A character's body offsets from its root `[..., B, 3]` (world frame) turned about world z
    by the twist about z of the rotation from its root (quaternion (w, x, y, z) `[..., 4]`) to
    the reference's root (`quat_ref`): delta = 2 atan2(z, w) of q_ref q^-1. For upright roots
    that is the difference of their headings, so what r_pj compares is what comparing both in
    their own heading frames compared (a yaw drift is r_qr's, not r_pj's); unlike a heading
    (the yaw of the root's forward axis, undefined when that axis is vertical: a crawl, the
    flight of a flip, where 3 degrees of pitch flipped it and ended the episode), delta is
    defined whenever the two roots are less than half a turn apart."""
    q, r = _contiguous(quat), _contiguous(quat_ref)
    w = r[..., 0] * q[..., 0] + r[..., 1] * q[..., 1] + r[..., 2] * q[..., 2] + r[..., 3] * q[..., 3]
    z = -r[..., 0] * q[..., 3] + r[..., 3] * q[..., 0] - r[..., 1] * q[..., 2] + r[..., 2] * q[..., 1]
    delta = 2.0 * np.arctan2(z, w)
    c, s = np.cos(delta)[..., None], np.sin(delta)[..., None]
    a = _contiguous(offsets)
    return np.stack([c * a[..., 0] - s * a[..., 1], s * a[..., 0] + c * a[..., 1], a[..., 2]], axis=-1)


def joint_position_errors(rel_pos: np.ndarray, rel_pos_ref: np.ndarray) -> np.ndarray:
    """(4 / B) sum_j ||p_j - p~_j||^2 (m^2) of body offsets from the root `[..., B, 3]`, the
    character's `yaw_aligned` to the reference's (see module docstring)."""
    d = _contiguous(rel_pos) - _contiguous(rel_pos_ref)
    lead = d.shape[:-2]
    return np.add.reduce((d * d).reshape(*lead, -1), axis=-1) * END_EFFECTORS_IN_DEEPMIMIC / max(1, d.shape[-2])


def joint_rotation_errors(balls: np.ndarray, balls_ref: np.ndarray, hinges: np.ndarray, hinges_ref: np.ndarray) -> np.ndarray:
    """sum_j angle^2 (rad^2) over ball joints (quaternions `[..., Nb, 4]`) and hinges (angles `[..., Nh]`)."""
    h = _contiguous(hinges) - _contiguous(hinges_ref)
    a = quat_angle(_contiguous(balls), _contiguous(balls_ref)) if np.shape(balls)[-2] else np.zeros((*h.shape[:-1], 0))
    return np.add.reduce(a * a, axis=-1) + np.add.reduce(h * h, axis=-1)  # np.sum's ufunc, without its wrapper


def joint_velocity_errors(qvel_joints: np.ndarray, qvel_joints_ref: np.ndarray) -> np.ndarray:
    """sum ||qdot - qdot~||^2 ((rad/s)^2) over the non-root DOF `[..., nv - 6]` -> `[...]`."""
    d = _contiguous(qvel_joints) - _contiguous(qvel_joints_ref)
    return (d[..., None, :] @ d[..., :, None])[..., 0, 0]


def com_error(com: np.ndarray, com_ref: np.ndarray) -> float:
    """||c - c~||^2 (m^2) of the centres of mass `[3]` (world frame)."""
    return float(com_errors(com, com_ref))


def root_rotation_error(quat: np.ndarray, quat_ref: np.ndarray) -> float:
    """Squared geodesic angle (rad^2) between root quaternions (w, x, y, z) `[4]`."""
    return float(root_rotation_errors(quat, quat_ref))


def joint_position_error(rel_pos: np.ndarray, rel_pos_ref: np.ndarray) -> float:
    """`joint_position_errors` of one state `[B, 3]`."""
    return float(joint_position_errors(rel_pos, rel_pos_ref))


def joint_rotation_error(balls: np.ndarray, balls_ref: np.ndarray, hinges: np.ndarray, hinges_ref: np.ndarray) -> float:
    """sum_j angle^2 (rad^2) over ball joints (quaternions `[Nb, 4]`) and hinges (angles `[Nh]`)."""
    return float(joint_rotation_errors(np.reshape(balls, (-1, 4)), np.reshape(balls_ref, (-1, 4)), hinges, hinges_ref))


def joint_velocity_error(qvel_joints: np.ndarray, qvel_joints_ref: np.ndarray) -> float:
    """sum ||qdot - qdot~||^2 ((rad/s)^2) over the non-root DOF `[nv - 6]`."""
    return float(joint_velocity_errors(qvel_joints, qvel_joints_ref))


POSITION_TERMS = ("root_position", "joint_position")
"""The terms whose errors are lengths (m^2): what the size normalization divides."""


def size_normalized_errors(errors: np.ndarray, leg_ratio: np.ndarray) -> np.ndarray:
    """The five terms' errors `[N, 5]` (`TERMS` order) with those of `POSITION_TERMS` divided by
    (lbar / lbar0)^2, `leg_ratio` `[N]` each body's mean leg length over the base humanoid's:
    Won & Lee 2019's reward normalization across body sizes (section 4.3, Table 1; METHOD.md A,
    "Reward normalization") carried over to the executor's position terms.

    Reconstruction: Won & Lee scale what a reward compares by the body's size, the target
    velocity by lbar / lbar0 (their Table 1, row "Velocity", with the asymmetry factor
    max(0.5, 1 - sigma_l / lbar)); the executor's retargeted references are scaled by the same
    ratio (root height and stride, `common.motion.retarget`), so a squared position error
    divided by its square scores an error of the same fraction of the body alike on a short and
    a tall body. The asymmetry factor is left out: it eases a task for an uneven body, it does
    not measure its size. Rotations and angular velocities are unchanged. A ratio of exactly 1
    (the base shape) leaves every error as it is, bit for bit. `ExecutorConfig.reward_normalization`
    turns it off."""
    out = np.array(errors, dtype=np.float64)
    ratio = np.asarray(leg_ratio, dtype=np.float64)
    cols = _indices(POSITION_TERMS)
    out[:, cols] = out[:, cols] / (ratio * ratio)[:, None]
    return out


def term_values(errors: np.ndarray, scales: tuple[float, ...]) -> np.ndarray:
    """exp(-k err) `[..., 5]` of the five terms' errors `[..., 5]` (in `TERMS` order)."""
    return np.exp(-np.asarray(scales, dtype=np.float64) * errors)


def weighted_sums(terms: np.ndarray, weights: tuple[float, ...]) -> np.ndarray:
    """r = sum_i w_i r_i (UniCon eq. 5) of terms `[..., 5]`, added in `TERMS` order."""
    total = 0
    for i, w in enumerate(weights):
        total = total + w * terms[..., i]
    return total


def reward_terms(errors: dict[str, float], scales: tuple[float, ...]) -> dict[str, float]:
    """{term: exp(-k err)} for the five terms (unweighted, each in (0, 1])."""
    values = term_values(np.array([errors[name] for name in TERMS], dtype=np.float64), scales)
    return {name: float(v) for name, v in zip(TERMS, values)}


def weighted_sum(terms: dict[str, float], weights: tuple[float, ...]) -> float:
    """r = sum_i w_i r_i (UniCon eq. 5)."""
    return float(weighted_sums(np.array([terms[name] for name in TERMS], dtype=np.float64), weights))


@functools.lru_cache(maxsize=None)
def _indices(watch: tuple[str, ...]) -> list[int]:
    """The places of the terms `watch` in `TERMS`."""
    return [TERMS.index(name) for name in watch]


def terminations(terms: np.ndarray, weights: tuple[float, ...], rule: str, alpha: float,
                 watch: tuple[str, ...] = TERMS) -> list[str | None]:
    """`termination` of each state's terms `[N, 5]`."""
    if rule == "per_term":
        below = terms[:, _indices(tuple(watch))] < alpha
        return [watch[f] if hit else None for f, hit in zip(np.argmax(below, axis=1).tolist(), below.any(axis=1).tolist())]
    if rule == "sum":
        return ["sum" if s < alpha else None for s in weighted_sums(terms, weights)]
    if rule == "none":
        return [None] * len(terms)
    raise ValueError(f"termination rule {rule!r} is not one of per_term, sum, none")


def termination(terms: dict[str, float], weights: tuple[float, ...], rule: str, alpha: float,
                watch: tuple[str, ...] = TERMS) -> str | None:
    """Why the episode ends now, or None: "per_term" ends it at the first term of `watch` below
    alpha (returns that term's name; UniCon watches all five), "sum" when the weighted sum is
    below alpha ("sum"), "none" never."""
    return terminations(np.array([[terms[name] for name in TERMS]], dtype=np.float64), weights, rule, alpha, watch)[0]


ACTION_BOUNDS = {"pd": 3.0, "torque": 1.0}
"""The largest |action| each actuation applies (`ExecutorEnv.step`'s clip): pd +-3 (times
`pd_action_scale` rad), torque +-1 (times the DOF's effort factor)."""


def action_rate_penalties(actions: np.ndarray, previous: np.ndarray, weight: float) -> np.ndarray:
    """w x mean_j (a_j - a'_j)^2 `[N]` of applied actions `[N, nu]` and the previous step's
    `[N, nu]` (mjlab's and ProtoMotions' action_rate_l2 as a mean over actuators, so the weight
    does not depend on the body's actuator count; `ExecutorConfig.action_rate_weight`)."""
    d = np.asarray(actions, dtype=np.float64) - previous
    return weight * np.add.reduce(d * d, axis=-1) / d.shape[-1]


def reward_range(weights: tuple[float, ...], action_rate_weight: float, actuation: str) -> tuple[float, float]:
    """(lowest, highest) step reward: the weighted terms lie in [0, sum of `weights`] (each term
    in (0, 1]), less at most w x (2 x bound)^2 of the action-rate penalty."""
    return -action_rate_weight * (2.0 * ACTION_BOUNDS[actuation]) ** 2, float(sum(weights))
