"""Frames and joint representations for the shape tasks' state (Won & Lee 2019, METHOD.md A:
s = (s_b, s_d, s_s), "the root's global yaw and planar position left out").

Everything here is numpy on qpos/qvel arrays in MuJoCo's layout (free root first). Joints are
represented as the PD actuators see them: a hinge by its angle, a ball joint by its rotation
vector (MuJoCo's actuator length on a ball joint's gear axis), so the observed joint vector,
the reference's and the action all live in the same `[nu]` space.
"""

from __future__ import annotations

import mujoco
import numpy as np


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) `[..., 4]` -> rotation vectors `[..., 3]` (rad), shortest arc.

    NOTE: the same as scipy's `Rotation.from_quat(q, scalar_first=True).as_rotvec()` (a test
    checks it), written out because it runs several times per control step: 14 us against
    scipy's 51 us for three joints."""
    q = np.asarray(q, dtype=np.float64)
    q = np.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    # NOTE: angle / sin(angle/2) -> 2 as s -> 0; the guarded ratio avoids 0/0 at identity.
    scale = np.where(s > 1e-9, angle / np.maximum(s, 1e-12), 2.0)
    return v * scale


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) `[4]` -> rotation matrix `[3, 3]`."""
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(q, dtype=np.float64))
    return m.reshape(3, 3)


def heading(mat: np.ndarray, forward_axis: int = 0) -> float:
    """Yaw (rad) of a body's forward axis (a column of its rotation matrix) projected on the floor."""
    f = mat[:, forward_axis]
    return float(np.arctan2(f[1], f[0]))


def yaw_matrix(yaw: float) -> np.ndarray:
    """Rotation `[3, 3]` about world z by `yaw` rad (heading frame -> world)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class JointLayout:
    """Where each actuated joint sits in qpos/qvel and in the `[nu]` joint vector.

    ball_qpos `[B, 4]` and hinge_qpos `[H]` index qpos; `to_vector(qpos)` gives the `[nu]`
    joint vector in actuator order (ball joints' three axes x, y, z; hinges' angle), which is
    also the order of `model.actuator_*` for the character presets (one actuator per DOF, in
    joint order: builder.add_pd_actuators).
    """

    def __init__(self, model: mujoco.MjModel):
        ball, hinge, order = [], [], []
        for j in range(1, model.njnt):
            a = int(model.jnt_qposadr[j])
            if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL:
                order.append(("ball", len(ball)))
                ball.append(np.arange(a, a + 4))
            else:
                order.append(("hinge", len(hinge)))
                hinge.append(a)
        self.ball_qpos = np.array(ball, dtype=np.int64).reshape(-1, 4)
        self.hinge_qpos = np.array(hinge, dtype=np.int64)
        self.order = order
        self.nu = 3 * len(ball) + len(hinge)
        # Where each entry of [ball rotation vectors (3 per ball) ..., hinge angles ...] goes in
        # actuator order: `to_vector` gathers with it once instead of concatenating per joint.
        position = {("ball", i): [3 * i, 3 * i + 1, 3 * i + 2] for kind, i in order if kind == "ball"}
        position |= {("hinge", i): [3 * len(ball) + i] for kind, i in order if kind == "hinge"}
        self._gather = np.array([p for key in order for p in position[key]], dtype=np.int64)
        if self.nu != model.nu or model.nv - 6 != self.nu:
            raise ValueError(f"joint layout has {self.nu} DOF but the model has nu={model.nu}, nv-6={model.nv - 6}: "
                             "the shape tasks need one PD actuator per DOF in joint order")

    def to_vector(self, qpos: np.ndarray) -> np.ndarray:
        """`[nq]` (or `[N, nq]`) qpos -> `[nu]` (or `[N, nu]`) joint vector in actuator order."""
        qpos = np.asarray(qpos)
        rv = (quat_to_rotvec(qpos[..., self.ball_qpos]) if len(self.ball_qpos)
              else np.zeros((*qpos.shape[:-1], 0, 3), dtype=qpos.dtype))
        flat = np.concatenate([rv.reshape(*rv.shape[:-2], 3 * len(self.ball_qpos)), qpos[..., self.hinge_qpos]], axis=-1)
        return flat[..., self._gather]


def root_frame_features(qpos: np.ndarray, qvel: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """Root height (m), root orientation in the heading frame (first two columns of the
    rotation matrix, 6), root linear and angular velocity in the heading frame (6): `[13]`.

    `frame` `[3, 3]` is the heading frame (yaw only) the state is expressed in. qvel's free
    root linear velocity is in the world frame, its angular velocity in the body frame.
    """
    rot = quat_to_mat(qpos[3:7])
    local = frame.T @ rot
    lin = frame.T @ qvel[0:3]
    ang = frame.T @ (rot @ qvel[3:6])
    return np.concatenate([[qpos[2]], local[:, 0], local[:, 1], lin, ang])
