"""Quaternion helpers in MuJoCo's (w, x, y, z) order, built on scipy's Rotation and Slerp.

scipy stores (x, y, z, w) by default; every function here takes and returns (w, x, y, z) so
the rest of the library and MuJoCo's qpos share one convention. Only what scipy lacks is
written by hand: batched per-joint slerp between two frames, the hemisphere fix.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

# NOTE: Y-up (DeepMimic) to MuJoCo Z-up: a position (x, y, z) -> (x, -z, y), a rotation is
# conjugated by the same map, which on a quaternion is (w, x, y, z) -> (w, x, -z, y).


def rot(q_wxyz: np.ndarray) -> Rotation:
    """Rotation(s) from quaternion(s) of shape (..., 4), (w, x, y, z); normalized by scipy."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    return Rotation.from_quat(q.reshape(-1, 4) if q.ndim > 2 else q, scalar_first=True)


def wxyz(r: Rotation) -> np.ndarray:
    """(w, x, y, z) of a Rotation, with w >= 0 so equal rotations compare equal."""
    q = r.as_quat(scalar_first=True, canonical=True)
    return q


def multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a*b of (..., 4) arrays in (w, x, y, z); broadcasting like numpy."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def conjugate(q: np.ndarray) -> np.ndarray:
    """Inverse of unit quaternions (..., 4)."""
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def y_up_to_z_up_quat(q: np.ndarray) -> np.ndarray:
    """(w, x, y, z) -> (w, x, -z, y): a Y-up rotation expressed in the Z-up world (data/README)."""
    q = np.asarray(q, dtype=np.float64)
    return np.stack([q[..., 0], q[..., 1], -q[..., 3], q[..., 2]], axis=-1)


def y_up_to_z_up_pos(p: np.ndarray) -> np.ndarray:
    """(x, y, z) -> (x, -z, y) for positions or axes of shape (..., 3)."""
    p = np.asarray(p, dtype=np.float64)
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def change_axes_quat(q: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Rotations (..., 4) re-expressed in axes rotated by the proper rotation matrix m (3, 3):
    the quaternion of m R m^T."""
    qm = wxyz(Rotation.from_matrix(m))
    return multiply(multiply(qm, np.asarray(q, dtype=np.float64)), conjugate(qm))


def slerp(q0: np.ndarray, q1: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """Per-element spherical interpolation of (..., 4) quaternions; alpha broadcasts over (...).

    Written by hand because scipy's Slerp interpolates one key sequence at a time, and here
    every joint of two frames is interpolated at once. Takes the short way round (q ~ -q).
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    alpha = np.asarray(alpha, dtype=np.float64)[..., None]
    d = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(d < 0.0, -q1, q1)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    sin_t = np.sin(theta)
    # NOTE: near-identical quaternions make sin(theta) ~ 0; lerp is exact to first order there.
    small = sin_t < 1e-6
    w0 = np.where(small, 1.0 - alpha, np.sin((1.0 - alpha) * theta) / np.where(small, 1.0, sin_t))
    w1 = np.where(small, alpha, np.sin(alpha * theta) / np.where(small, 1.0, sin_t))
    out = w0 * q0 + w1 * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def continuous(q: np.ndarray) -> np.ndarray:
    """Flip signs along axis 0 of a (T, ..., 4) sequence so neighbours lie in one hemisphere."""
    q = np.array(q, dtype=np.float64, copy=True)
    for k in range(1, q.shape[0]):
        flip = np.sum(q[k] * q[k - 1], axis=-1) < 0.0
        q[k][flip] *= -1.0
    return q


def angular_velocity_local(q0: np.ndarray, q1: np.ndarray, dt_s: float) -> np.ndarray:
    """Constant angular velocity (rad/s, child frame) that takes q0 to q1 in dt_s; (..., 3).

    The quaternion difference q0^-1 q1 as a rotation vector over dt: MuJoCo's convention for
    ball and free-joint angular velocities (local frame), and exact for slerp between frames.
    """
    return (rot(q0).inv() * rot(q1)).as_rotvec().reshape(np.shape(q0)[:-1] + (3,)) / dt_s


def quat_angle(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Geodesic angle (rad, in [0, pi]) between unit quaternions (w, x, y, z), `[..., 4]` -> `[...]`."""
    dot = np.abs(np.sum(np.asarray(q1) * np.asarray(q2), axis=-1))
    # NOTE: minimum/maximum rather than np.clip: the same values, without np.clip's dispatch,
    # which cost more than the arithmetic on these few quaternions.
    return 2.0 * np.arccos(np.minimum(np.maximum(dot, 0.0), 1.0))
