"""The leg pose solve of the retargeting: lift a foot that a shape change left below the floor.

Won & Lee 2019 (METHOD.md A) solve the pose after the shape operator so that the feet touch
the ground. Per frame and foot (`retarget.retarget_qpos` says which), damped least squares on
that leg's joints with MuJoCo's Jacobian raise the foot body by its penetration while keeping
its orientation and horizontal position. A knee the clip bends one way only stays on that
side (`bend_side_bounds`), so the solution does not flip between frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from common.motion.retarget_config import RetargetConfig


def _leg_dofs(model: mujoco.MjModel, body: int) -> np.ndarray:
    """DOF indices of the joints between the root body and `body` (inclusive of `body`)."""
    dofs = []
    root = int(model.jnt_bodyid[0])
    b = body
    while b > 0 and b != root:
        for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b]):
            n = {mujoco.mjtJoint.mjJNT_BALL: 3, mujoco.mjtJoint.mjJNT_HINGE: 1, mujoco.mjtJoint.mjJNT_SLIDE: 1}[int(model.jnt_type[j])]
            dofs.extend(range(model.jnt_dofadr[j], model.jnt_dofadr[j] + n))
        b = int(model.body_parentid[b])
    return np.array(sorted(dofs), dtype=np.int64)


@dataclass(frozen=True)
class Leg:
    """What the leg solve needs of one foot, computed once per retarget: the foot body, the DOFs
    between root and foot, and the limited hinges among them (qpos address, lower, upper; a
    hinge that may turn both ways but that the clip bends one way only is narrowed to that
    side, `bend_side_bounds`, and `hinge_side` says which: +1, -1, or 0 if not narrowed)."""

    body: int
    dofs: np.ndarray
    hinge_qpos: np.ndarray
    hinge_lo: np.ndarray
    hinge_hi: np.ndarray
    hinge_side: np.ndarray
    side_by_dof: np.ndarray
    """`hinge_side` per entry of `dofs` (0 for the other DOFs)."""

    @staticmethod
    def of(model: mujoco.MjModel, body: int, qpos_frames: np.ndarray | None = None) -> "Leg":
        dofs = _leg_dofs(model, body)
        joints = sorted(set(model.dof_jntid[dofs].tolist()))
        hinges = [j for j in joints if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE and model.jnt_limited[j]]
        adr = model.jnt_qposadr[hinges].astype(np.int64)
        lo, hi = model.jnt_range[hinges, 0].copy(), model.jnt_range[hinges, 1].copy()
        side = np.zeros(len(hinges))
        if qpos_frames is not None:
            new_lo, new_hi = bend_side_bounds(qpos_frames[:, adr], lo, hi)
            side = np.where(new_lo > lo, 1.0, np.where(new_hi < hi, -1.0, 0.0))
            lo, hi = new_lo, new_hi
        by_dof = np.zeros(len(dofs))
        for j, sd in zip(hinges, side):
            by_dof[dofs == model.jnt_dofadr[j]] = sd
        return Leg(body, dofs, adr, lo, hi, side, by_dof)

    def clamp_hinges(self, data: mujoco.MjData) -> None:
        """Keep limited hinge joints (knees) inside their range and on the clip's bend side: a
        solve must not bend a knee backward."""
        data.qpos[self.hinge_qpos] = np.clip(data.qpos[self.hinge_qpos], self.hinge_lo, self.hinge_hi)

    def unstraighten(self, data: mujoco.MjData, angle: float = 0.05) -> None:
        """Bend each narrowed hinge that is within `angle` (rad) of straight to `angle` on its
        side: a straight leg is singular, and the solve's steps would push the knee against its
        new 0 bound and stall there (a foot left 13 cm below the floor, measured)."""
        q = data.qpos[self.hinge_qpos]
        data.qpos[self.hinge_qpos] = np.where((self.hinge_side != 0.0) & (np.abs(q) < angle), self.hinge_side * angle, q)


BEND_EPS_RAD = 1e-3
"""A hinge whose clip angle never goes past 0 by more than this, on one side, bends only the
other way (`bend_side_bounds`)."""


def bend_side_bounds(angles: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joint bounds `(lo, hi)` of limited hinges narrowed to the side of 0 their clip angles
    `angles [T, H]` keep to: a knee the clip bends only one way (a quadruped's front knees
    negative, its hind knees positive) gets [lo, 0] or [0, hi]; a hinge the clip moves through
    0 (or never moves) keeps its range.

    Why: the quadruped's knees may turn either way (range +-2.4 rad). A straight leg is a
    singular pose, and the leg solve that lifts a too-long leg's foot (Won & Lee 2019, METHOD.md
    A: the per-frame pose solve after F) would bend the knee whichever way its first step
    happened to go, frame by frame: measured on 150 random quadruped shapes, every one had a
    knee that flipped by 1.9-3.6 rad between two frames of its reference, a PD target no body
    can follow. A hinge whose range is already one-sided (a biped's knee, [0, 2.3]) is
    unchanged."""
    angles = np.asarray(angles, dtype=np.float64)
    lo, hi = np.array(lo, dtype=np.float64), np.array(hi, dtype=np.float64)
    if angles.size == 0:
        return lo, hi
    bends_neg = (angles.max(axis=0) <= BEND_EPS_RAD) & (angles.min(axis=0) < -BEND_EPS_RAD)
    bends_pos = (angles.min(axis=0) >= -BEND_EPS_RAD) & (angles.max(axis=0) > BEND_EPS_RAD)
    hi = np.where(bends_neg, np.minimum(hi, 0.0), hi)
    lo = np.where(bends_pos, np.maximum(lo, 0.0), lo)
    return lo, hi


def lift_foot(model: mujoco.MjModel, data: mujoco.MjData, leg: Leg, lift_m: float, cfg: RetargetConfig) -> None:
    """Raise a foot body by lift_m (m) keeping its orientation, moving only the leg's DOFs; in
    place on data.qpos. Damped Gauss-Newton; the normal equations (n_dofs square) are solved
    with MuJoCo's Cholesky, which costs a tenth of numpy's per-call overhead at this size."""
    body, dofs, n = leg.body, leg.dofs, len(leg.dofs)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    target_p = data.xpos[body] + np.array([0.0, 0.0, lift_m])
    target_q = data.xquat[body].copy()
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    err, err_r, qv = np.zeros(6), np.zeros(3), np.zeros(model.nv)
    w = cfg.ik_orientation_weight_m
    damping = cfg.ik_damping * np.eye(n)
    jac = np.zeros((6, n))
    step = np.zeros(n)
    for _ in range(cfg.ik_iterations):
        err[:3] = target_p - data.xpos[body]
        if err[0] * err[0] + err[1] * err[1] + err[2] * err[2] < 1e-8:
            break
        mujoco.mj_jacBody(model, data, jacp, jacr, body)
        mujoco.mju_subQuat(err_r, target_q, data.xquat[body])
        err[3:] = w * err_r
        jac[:3] = jacp[:, dofs]
        jac[3:] = w * jacr[:, dofs]
        normal = jac.T @ jac + damping
        mujoco.mju_cholFactor(normal, 0.0)
        mujoco.mju_cholSolve(step, normal, jac.T @ err)
        qv[dofs] = step
        mujoco.mj_integratePos(model, data.qpos, qv, 1.0)
        leg.clamp_hinges(data)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
