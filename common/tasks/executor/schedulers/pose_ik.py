"""Joint positions -> a pose of the character (qpos): the simple inverse kinematics of the video
scheduler (UniCon 2020, METHOD.md B "Schedulers": "video: 3-D poses arrive over UDP").

Input: the world position of every body origin of the model (world excluded, model order, as
`pose_packet.joint_names`). Output: a qpos whose bodies sit on those positions as far as the
model's own bone lengths allow. Each body's world rotation is found from its children's
positions, parents first (MuJoCo orders bodies so), and turned into its joint's value relative
to the parent:

- a body with two or more children off one line (the free root: chest and hips; the chest:
  neck and shoulders): the rotation that best maps the rest offsets of its children onto the
  observed ones (Kabsch; exact for a rigid, same-sized body);
- a ball joint with one child that is a hinge with one child (shoulder-elbow-wrist,
  hip-knee-ankle): the bone points at the child, and the twist about the bone puts the hinge
  axis normal to the plane of the two segments, on the side where the hinge bends within its
  range; for an almost straight limb (the plane is undefined) the twist fades to the rest
  twist relative to the parent;
- a ball joint with one other child: the shortest rotation from the rest bone to the observed;
- a hinge: the signed angle between the rest and the observed child direction about its axis
  (the angle between the segments), clipped to its range;
- a ball joint with no child (neck, ankles: the positions say nothing about the head or feet):
  the rest pose, except `level_leaves` (default: ankles), turned flat: the foot keeps the
  shin's heading with no pitch or roll, at most `max_leaf_rad` from the rest.

Assumes every joint at its body's origin (true for the presets; checked).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from common.tasks.observations import quat_to_rotvec

_BALL, _HINGE, _FREE = int(mujoco.mjtJoint.mjJNT_BALL), int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_FREE)
STRAIGHT_SIN = math.sin(math.radians(15.0))
"""Below this sine of the angle between two segments the limb counts as straight (twist fades)."""


def _unit(v: np.ndarray) -> np.ndarray:
    n = math.sqrt(float(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
    return v / n if n > 1e-12 else np.zeros(3)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of 3-vectors (np.cross costs 10x more on single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def kabsch(rest: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """The rotation `[3, 3]` R minimizing sum |R rest_i - observed_i|^2 (rows are vectors)."""
    u, _, vt = np.linalg.svd(rest.T @ observed)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def _mat_to_quat(r: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(r).reshape(9))
    return q


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(q, dtype=np.float64))
    return m.reshape(3, 3)


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation `[3, 3]` by `angle` about the unit `axis` (Rodrigues; scipy costs 20x more here)."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


class PositionIK:
    """`solve(positions [nbody - 1, 3]) -> qpos [nq]` for one model (see the module docstring)."""

    def __init__(self, model: mujoco.MjModel, level_leaves: tuple[str, ...] = ("ankle",), max_leaf_rad: float = 1.0):
        if model.jnt_type[0] != _FREE or model.jnt_bodyid[0] != 1:
            raise ValueError("PositionIK needs a model whose body 1 is the free root")
        if np.any(np.abs(model.jnt_pos) > 1e-9):
            raise ValueError("PositionIK assumes every joint at its body's origin (jnt_pos = 0)")
        self.model = model
        nb = model.nbody
        self.children: list[list[int]] = [[] for _ in range(nb)]
        for b in range(2, nb):
            self.children[int(model.body_parentid[b])].append(b)
        self.body_rot = [_quat_to_mat(model.body_quat[b]) for b in range(nb)]
        """Each body's rest rotation in its parent's frame."""
        self.joint = [int(model.body_jntadr[b]) if model.body_jntnum[b] == 1 else -1 for b in range(nb)]
        for b in range(1, nb):
            if model.body_jntnum[b] > 1:
                raise ValueError(f"body {model.body(b).name!r} has {model.body_jntnum[b]} joints; PositionIK takes one per body")
        self.level = [any(model.body(b).name.endswith(w) for w in level_leaves) for b in range(nb)]
        self.max_leaf_rad = float(max_leaf_rad)
        self._limbs: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, float]] = {}

    def solve(self, positions: np.ndarray) -> np.ndarray:
        """qpos `[nq]` of the pose whose body origins are `positions` `[nbody - 1, 3]` (metres)."""
        m = self.model
        p = np.zeros((m.nbody, 3))
        p[1:] = np.asarray(positions, dtype=np.float64)
        qpos = m.qpos0.copy()
        world = [np.eye(3) for _ in range(m.nbody)]
        for b in range(1, m.nbody):
            pre = world[int(m.body_parentid[b])] @ self.body_rot[b]
            j = self.joint[b]
            if j < 0:
                world[b] = pre
                continue
            adr, kind = int(m.jnt_qposadr[j]), int(m.jnt_type[j])
            if kind == _FREE:
                world[b] = self._rigid(b, p, pre)
                qpos[adr : adr + 3] = p[b]
                qpos[adr + 3 : adr + 7] = _mat_to_quat(world[b])
            elif kind == _BALL:
                world[b] = self._ball(b, p, pre)
                qpos[adr : adr + 4] = _mat_to_quat(pre.T @ world[b])
            elif kind == _HINGE:
                angle = self._hinge_angle(b, p, pre)
                qpos[adr] = angle
                world[b] = pre @ _axis_angle(m.jnt_axis[j], angle)
            else:
                raise ValueError(f"joint {m.joint(j).name!r}: PositionIK handles free, ball and hinge joints")
        return qpos

    # ---- the rules ----

    def _rigid(self, b: int, p: np.ndarray, pre: np.ndarray) -> np.ndarray:
        """World rotation of a body from its children's offsets (Kabsch); `pre` without children."""
        kids = self.children[b]
        if not kids:
            return pre
        rest = np.stack([self.model.body_pos[c] for c in kids])
        seen = np.stack([p[c] - p[b] for c in kids])
        if len(kids) == 1:
            return self._swing(rest[0], seen[0], pre)
        return kabsch(rest, seen)

    def _ball(self, b: int, p: np.ndarray, pre: np.ndarray) -> np.ndarray:
        kids = self.children[b]
        if len(kids) >= 2:
            return self._rigid(b, p, pre)
        if len(kids) == 1:
            c = kids[0]
            grand = self.children[c]
            if self.joint[c] >= 0 and self.model.jnt_type[self.joint[c]] == _HINGE and len(grand) == 1:
                return self._limb(b, c, grand[0], p, pre)
            return self._swing(self.model.body_pos[c], p[c] - p[b], pre)
        return self._leaf(b, pre)

    def _swing(self, rest: np.ndarray, seen: np.ndarray, pre: np.ndarray) -> np.ndarray:
        """pre turned by the shortest rotation taking the rest bone (body frame) to the observed."""
        a, s = _unit(pre @ rest), _unit(seen)
        axis = _cross(a, s)
        sin, cos = float(np.linalg.norm(axis)), float(np.dot(a, s))
        if sin < 1e-9:
            return pre if cos > 0 else _axis_angle(_unit(_cross(a, [1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else
                                                        _cross(a, [0.0, 1.0, 0.0])), math.pi) @ pre
        return _axis_angle(axis / sin, math.atan2(sin, cos)) @ pre

    def _limb(self, b: int, c: int, g: int, p: np.ndarray, pre: np.ndarray) -> np.ndarray:
        """World rotation of a ball joint b whose child c is a hinge with child g (module docstring)."""
        bone, axis, rest, bend = self._limb_rest(c)
        u = _unit(p[c] - p[b])
        f = _unit(p[g] - p[c])
        if not np.any(u):
            return pre
        fallback = _unit(pre @ axis - np.dot(pre @ axis, u) * u)
        perp = f - np.dot(f, u) * u
        w = min(float(np.linalg.norm(perp)) / STRAIGHT_SIN, 1.0)
        plane = _cross(u, bend * _unit(perp)) if w > 0 else np.zeros(3)
        n = _unit(w * plane + (1.0 - w) * fallback)
        if not np.any(n):
            n = plane if np.any(plane) else _unit(_cross(u, [0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else _cross(u, [1.0, 0.0, 0.0]))
        n = _unit(n - np.dot(n, u) * u)
        seen = np.stack([u, n, _cross(u, n)], axis=1)
        return seen @ rest.T

    def _limb_rest(self, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """(bone direction, hinge axis normal to it, the frame [bone, axis, bone x axis], the sign
        the hinge bends to) of the limb whose hinge body is c, in its parent's frame; cached."""
        if c not in self._limbs:
            m = self.model
            j = self.joint[c]
            bone = _unit(m.body_pos[c])
            axis = _unit(self.body_rot[c] @ m.jnt_axis[j])
            axis = _unit(axis - np.dot(axis, bone) * bone)
            lo, hi = m.jnt_range[j]
            bend = 1.0 if not m.jnt_limited[j] or lo + hi >= 0 else -1.0
            self._limbs[c] = (bone, axis, np.stack([bone, axis, _cross(bone, axis)], axis=1), bend)
        return self._limbs[c]

    def _hinge_angle(self, c: int, p: np.ndarray, pre: np.ndarray) -> float:
        m = self.model
        j = self.joint[c]
        kids = self.children[c]
        if len(kids) != 1:
            return 0.0
        g = kids[0]
        a = _unit(m.jnt_axis[j])
        rest = m.body_pos[g] - np.dot(m.body_pos[g], a) * a
        seen = pre.T @ (p[g] - p[c])
        seen = seen - np.dot(seen, a) * a
        if np.linalg.norm(rest) < 1e-9 or np.linalg.norm(seen) < 1e-9:
            return 0.0
        angle = math.atan2(float(np.dot(a, _cross(rest, seen))), float(np.dot(rest, seen)))
        if m.jnt_limited[j]:
            angle = float(np.clip(angle, m.jnt_range[j][0], m.jnt_range[j][1]))
        return angle

    def _leaf(self, b: int, pre: np.ndarray) -> np.ndarray:
        """A ball joint without children: the rest pose, or (a `level_leaves` body) flat."""
        if not self.level[b]:
            return pre
        fwd = pre[:, 0]
        yaw = math.atan2(fwd[1], fwd[0]) if math.hypot(fwd[0], fwd[1]) > 1e-6 else 0.0
        c, s = math.cos(yaw), math.sin(yaw)
        flat = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        local = quat_to_rotvec(_mat_to_quat(pre.T @ flat))
        angle = float(np.linalg.norm(local))
        if angle <= self.max_leaf_rad:
            return flat
        return pre @ _axis_angle(local / angle, self.max_leaf_rad)
