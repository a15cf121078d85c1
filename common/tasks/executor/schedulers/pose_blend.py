"""Whole-pose arithmetic on a character's qpos rows, shared by the run-time schedulers (UniCon
2020, METHOD.md B "Schedulers": slerp transition frames between clips, a loop seam smoothed,
velocities of generated frames).

A pose is a qpos row of a model whose first joint is the free root (qpos[0:7] = position,
quaternion wxyz) followed by ball (quaternion) and hinge/slide (scalar) joints. `PoseMath`
splits a row into its "linear" columns (root position, hinge angles: lerped, added) and its
quaternions (root and ball joints: slerped, composed), all vectorised over rows, so a
transition of N frames is one numpy call instead of N x joints Python slerps.
"""

from __future__ import annotations

import mujoco
import numpy as np

from common.motion import quat


class PoseMath:
    """Vectorised blends, differences and velocities of qpos rows `[..., nq]` of one model."""

    def __init__(self, model: mujoco.MjModel):
        if model.njnt == 0 or model.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE or model.jnt_qposadr[0] != 0:
            raise ValueError("PoseMath needs a model whose first joint is the free root at qpos[0:7]")
        quats, lin = [np.arange(3, 7)], [0, 1, 2]
        for j in range(1, model.njnt):
            a = int(model.jnt_qposadr[j])
            kind = int(model.jnt_type[j])
            if kind == int(mujoco.mjtJoint.mjJNT_BALL):
                quats.append(np.arange(a, a + 4))
            elif kind in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
                lin.append(a)
            else:
                raise ValueError(f"joint {model.joint(j).name!r}: only the first joint may be free")
        self.model = model
        self.quat_cols = np.stack(quats)
        """`[K, 4]` qpos columns of the root quaternion (row 0) and every ball joint's."""
        self.lin_cols = np.array(lin, dtype=np.int64)
        """qpos columns blended linearly: the root position, then hinge angles."""

    def blend(self, qa: np.ndarray, qb: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
        """(1 - alpha) qa + alpha qb per row: lerp of the linear columns, slerp of the
        quaternions. qa, qb `[nq]` or `[N, nq]` (broadcast), alpha scalar or `[N]`."""
        qa, qb = np.asarray(qa, dtype=np.float64), np.asarray(qb, dtype=np.float64)
        a = np.asarray(alpha, dtype=np.float64)
        shape = np.broadcast_shapes(qa.shape, qb.shape, a.shape + qa.shape[-1:])
        qa, qb, a = np.broadcast_to(qa, shape), np.broadcast_to(qb, shape), np.broadcast_to(a, shape[:-1])
        out = np.array(qa, copy=True)
        out[..., self.lin_cols] = (1.0 - a[..., None]) * qa[..., self.lin_cols] + a[..., None] * qb[..., self.lin_cols]
        out[..., self.quat_cols] = quat.slerp(qa[..., self.quat_cols], qb[..., self.quat_cols], a[..., None])
        return out

    def difference(self, qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
        """The offset d with `add(qa, d, 1) == qb`: linear columns qb - qa, quaternions qb qa^-1
        (in the parent frame; the root's in the world). Same shape as qa."""
        qa, qb = np.asarray(qa, dtype=np.float64), np.asarray(qb, dtype=np.float64)
        d = np.zeros(np.broadcast_shapes(qa.shape, qb.shape))
        d[..., self.lin_cols] = qb[..., self.lin_cols] - qa[..., self.lin_cols]
        d[..., self.quat_cols] = quat.multiply(qb[..., self.quat_cols], quat.conjugate(qa[..., self.quat_cols]))
        return d

    def add(self, q: np.ndarray, offset: np.ndarray, fraction: np.ndarray | float) -> np.ndarray:
        """q with `fraction` of an offset (from `difference`) applied: linear columns plus
        fraction x offset, quaternions pre-multiplied by the offset's rotation scaled by the
        fraction (a slerp from identity). q `[N, nq]`, offset `[nq]`, fraction `[N]` or scalar."""
        q = np.asarray(q, dtype=np.float64)
        f = np.broadcast_to(np.asarray(fraction, dtype=np.float64), q.shape[:-1])
        out = np.array(q, copy=True)
        out[..., self.lin_cols] = q[..., self.lin_cols] + f[..., None] * offset[..., self.lin_cols]
        ident = np.zeros(4)
        ident[0] = 1.0
        part = quat.slerp(ident, np.broadcast_to(offset[..., self.quat_cols], q[..., self.quat_cols].shape), f[..., None])
        out[..., self.quat_cols] = quat.multiply(part, q[..., self.quat_cols])
        return out

    def velocity(self, q_prev: np.ndarray, q_next: np.ndarray, span_s: float) -> np.ndarray:
        """`[nv]` velocity taking q_prev to q_next in span_s seconds."""
        v = np.zeros(self.model.nv)
        mujoco.mj_differentiatePos(self.model, v, span_s, q_prev, q_next)
        return v

    def normalized(self, q: np.ndarray) -> np.ndarray:
        """q with every quaternion scaled to unit length (after sums or user input)."""
        out = np.array(q, dtype=np.float64, copy=True)
        qs = out[..., self.quat_cols]
        out[..., self.quat_cols] = qs / np.linalg.norm(qs, axis=-1, keepdims=True)
        return out

    def joint_angle_change(self, qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
        """`[..., K - 1 + H]` per joint: the rotation angle (rad) between qa's and qb's ball joint
        quaternions, then the absolute hinge differences (root excluded): a jump measure."""
        d = self.difference(qa, qb)
        w = np.clip(np.abs(d[..., self.quat_cols[1:, 0]]), 0.0, 1.0)
        ball = 2.0 * np.arccos(w)
        hinge = np.abs(d[..., self.lin_cols[3:]])
        return np.concatenate([ball, hinge], axis=-1)
