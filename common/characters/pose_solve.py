"""The standing-pose solve of Won & Lee 2019 (section 3; METHOD.md A).

    q* = argmin_q  sum_i sum_j ||c_ij(q) - c0_ij||^2 + w_q ||q - q0||^2

over feet i and the 4 lower vertices j of each box foot. The root is frozen except its height;
the joints on the chains from the root to the feet are free (ball joints through a rotation
vector delta, q = q0 (x) exp(delta), hinges through their angle), bounded by the hinge limits.
Solved with scipy's SLSQP and the analytic gradient from MuJoCo's forward-kinematics Jacobian
(`mj_jac`; a ball joint's columns are multiplied by the SO(3) right Jacobian of delta, since
MuJoCo's ball velocities are body-frame angular velocities).

Targets c0_ij: the new character's own foot vertices at q0, dropped onto the ground (z = 0).
The paper takes them from the base character standing; after F has moved the hips, the base
points would force legs apart or together, so this keeps the same meaning (feet flat where
they hang) for every shape. The height error is weighted `w_z` times the horizontal one
(a reconstruction choice, configurable) because "every vertex on the ground" is the hard
requirement and the horizontal targets are only a preference.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.optimize import minimize

from common.characters.errors import ShapeError


@dataclass(frozen=True)
class PoseSolveConfig:
    """Weights and limits of the standing-pose solve."""

    w_q: float = 1e-4
    """weight of ||q - q0||^2 (rad^2) against the squared vertex error (m^2)"""
    w_z: float = 10.0
    """weight of the vertical vertex error relative to the horizontal one"""
    max_iter: int = 200
    """SLSQP iterations"""
    ball_bound_rad: float = 1.5
    """bound on each rotation-vector component of a ball joint"""
    hinge_starts_rad: tuple[float, ...] = (0.1, 0.6, 1.2)
    """initial bends of every hinge on a leg chain (into its larger side of the range), tried
    in turn until the feet are within `accept_m` of the ground (legs of very different
    lengths otherwise stop at a local minimum with the longer leg straight)"""
    accept_m: float = 5e-4
    """largest vertex height error [m] that ends the restarts"""


def lower_vertices(model: mujoco.MjModel, data: mujoco.MjData, geom_id: int) -> np.ndarray:
    """Local coordinates [4, 3] (geom frame, m) of the 4 box corners lowest in the world now."""
    size = model.geom_size[geom_id]
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    local = signs * size
    world = data.geom_xpos[geom_id] + local @ data.geom_xmat[geom_id].reshape(3, 3).T
    return local[np.argsort(world[:, 2])[:4]]


def foot_points_world(model, data, geom_ids, locals_) -> np.ndarray:
    """World positions [F*4, 3] of the given geom-frame points."""
    out = []
    for gid, loc in zip(geom_ids, locals_):
        out.append(data.geom_xpos[gid] + loc @ data.geom_xmat[gid].reshape(3, 3).T)
    return np.concatenate(out)


def _right_jacobian(phi: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(phi))
    k = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if theta < 1e-6:
        return np.eye(3) - 0.5 * k
    return np.eye(3) - (1 - np.cos(theta)) / theta**2 * k + (theta - np.sin(theta)) / theta**3 * (k @ k)


def _chain_joints(model: mujoco.MjModel, body_ids) -> list[int]:
    joints: set[int] = set()
    for b in body_ids:
        while b > 0:
            for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b]):
                if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE:
                    joints.add(j)
            b = model.body_parentid[b]
    return sorted(joints)


def solve_standing_pose(model: mujoco.MjModel, q0: np.ndarray, foot_geom_ids: list[int],
                        cfg: PoseSolveConfig = PoseSolveConfig()) -> np.ndarray:
    """Return q* [nq]: q0 with the root height and the leg joints set so every foot's four
    lower vertices lie on the ground z = 0 (see module docstring). q0's root must be a free
    joint at qpos[0:7]."""
    data = mujoco.MjData(model)
    data.qpos[:] = q0
    mujoco.mj_kinematics(model, data)
    locals_ = [lower_vertices(model, data, g) for g in foot_geom_ids]
    rest = foot_points_world(model, data, foot_geom_ids, locals_)
    q_start = q0.copy()
    q_start[2] -= rest[:, 2].min()
    target = rest.copy()
    target[:, 2] = 0.0
    feet_bodies = [int(model.geom_bodyid[g]) for g in foot_geom_ids]
    joints = _chain_joints(model, feet_bodies)
    # Decision vector x = [root dz, per joint: 3 (ball) or 1 (hinge)].
    layout = []
    lo, hi = [-np.inf], [np.inf]
    for j in joints:
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL:
            layout.append((j, 3))
            lo += [-cfg.ball_bound_rad] * 3
            hi += [cfg.ball_bound_rad] * 3
        else:
            layout.append((j, 1))
            q_ref = q0[model.jnt_qposadr[j]]
            rng = model.jnt_range[j] if model.jnt_limited[j] else (-np.pi, np.pi)
            lo.append(rng[0] - q_ref)
            hi.append(rng[1] - q_ref)
    n = len(lo)
    # NOTE: a straight knee is a singular point (bending it does not move the foot to first
    # order), and q0 has knees straight, often at a limit: start every hinge bent into its
    # range so the solver can see that bending shortens the leg.
    def start(bend: float) -> np.ndarray:
        x = np.zeros(n)
        k = 1
        for j, width in layout:
            if width == 1:
                x[k] = min(max(bend * (1.0 if hi[k] >= -lo[k] else -1.0), lo[k]), hi[k])
            k += width
        return x

    weight = np.tile([1.0, 1.0, cfg.w_z], len(target))
    point_body = np.repeat(feet_bodies, 4)
    jacp = np.zeros((3, model.nv))

    def set_q(x: np.ndarray) -> list[np.ndarray | None]:
        q = q_start.copy()
        q[2] += x[0]
        jr: list[np.ndarray | None] = []
        k = 1
        for j, width in layout:
            adr = model.jnt_qposadr[j]
            if width == 3:
                angle = float(np.linalg.norm(x[k:k + 3]))
                dq, out = np.empty(4), np.empty(4)
                mujoco.mju_axisAngle2Quat(dq, x[k:k + 3] / max(angle, 1e-12), angle)
                mujoco.mju_mulQuat(out, q_start[adr:adr + 4], dq)
                q[adr:adr + 4] = out
                jr.append(_right_jacobian(x[k:k + 3]))
            else:
                q[adr] += x[k]
                jr.append(None)
            k += width
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        return jr

    def fun_grad(x: np.ndarray) -> tuple[float, np.ndarray]:
        jr = set_q(x)
        mujoco.mj_comPos(model, data)
        pts = foot_points_world(model, data, foot_geom_ids, locals_)
        res = (pts - target).ravel()
        f = float(np.sum(weight * res**2) + cfg.w_q * np.sum(x[1:] ** 2))
        g = np.zeros(n)
        g[1:] = 2.0 * cfg.w_q * x[1:]
        wres = (2.0 * weight * res).reshape(-1, 3)
        gv = np.zeros(model.nv)  # d f / d qvel, summed over points
        for p, body, wr in zip(pts, point_body, wres):
            mujoco.mj_jac(model, data, jacp, None, p, int(body))
            gv += wr @ jacp
        g[0] += gv[2]  # free joint: dof 2 is world z translation
        k = 1
        for (j, width), r in zip(layout, jr):
            dadr = model.jnt_dofadr[j]
            if width == 3:
                g[k:k + 3] += gv[dadr:dadr + 3] @ r
            else:
                g[k] += gv[dadr]
            k += width
        return f, g

    result, best_err = None, np.inf
    for bend in cfg.hinge_starts_rad:
        trial = minimize(fun_grad, start(bend), jac=True, method="SLSQP", bounds=list(zip(lo, hi)),
                         options={"maxiter": cfg.max_iter, "ftol": 1e-12})
        set_q(trial.x)
        err = float(np.abs(foot_points_world(model, data, foot_geom_ids, locals_)[:, 2]).max())
        if err < best_err:
            result, best_err = trial, err
        if err < cfg.accept_m:
            break
    if not np.all(np.isfinite(result.x)):
        raise ShapeError("standing-pose solve failed (non-finite pose); the shape is probably degenerate")
    set_q(result.x)
    pts = foot_points_world(model, data, foot_geom_ids, locals_)
    q = data.qpos.copy()
    q[2] -= float(np.mean(pts[:, 2]))  # exact vertical fit of the residual
    return q
