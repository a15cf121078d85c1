"""UniCon's agent-centric observation (METHOD.md B "Observation"; Wang et al. 2020, 4.1).

A character state X = [p_r, q_r, p_j, q_j, v_r, w_r, v_j, w_j] is read off MuJoCo as `BodyKin`
(every body's position, rotation, linear and angular velocity in the world). Then

    o(X) = [root height, root tilt, p_j, q_j, v_r, w_r, v_j, w_j]   all in X's own root frame
    y(X~; X) = target root position and rotation in the actual root frame X
    s_t = [o(X_now), o(X~_t+1), y(X~_t+1; X_now), ..., o(X~_t+tau), y(X~_t+tau; X_now)]

"Everything else in X's own root frame" leaves the root's own rotation trivial, so its tilt
(the root rotation in its heading frame: yaw removed) stands in for it. Rotations are the first
two columns of the matrix (6 numbers, continuous). Nothing here depends on where the character
stands on the floor or which way it faces: the observation is unchanged under a rigid
horizontal translation and yaw of the character and its targets together (a test checks it).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import mujoco
import numpy as np

from common.tasks.observations import heading, yaw_matrix


@dataclass(frozen=True)
class BodyKin:
    """Bodies 1..nbody-1 of a model (index 0 here is the root): world positions `[B, 3]` (m),
    rotations `[B, 3, 3]`, linear velocities of the body origins `[B, 3]` (m/s) and angular
    velocities `[B, 3]` (rad/s), both in the world frame; and the centre of mass `[3]`."""

    pos: np.ndarray
    rot: np.ndarray
    lin: np.ndarray
    ang: np.ndarray
    com: np.ndarray

    @cached_property
    def heading_frame(self) -> np.ndarray:
        """The root's heading frame `[3, 3]` (yaw only; body x forward)."""
        return yaw_matrix(heading(self.rot[0]))

    def relative_positions(self) -> np.ndarray:
        """Non-root bodies relative to the root, in the root's heading frame `[B - 1, 3]`."""
        return (self.pos[1:] - self.pos[0]) @ self.heading_frame


def read_kinematics(model: mujoco.MjModel, data: mujoco.MjData, bodies: np.ndarray) -> BodyKin:
    """`BodyKin` of `bodies` (ids, root first) from `data` after `mj_kinematics`, `mj_comPos` and
    `mj_comVel` (or `mj_forward`/`mj_step`).

    NOTE: `cvel` is the spatial velocity (angular, linear) about the subtree centre of mass of
    each body's kinematic tree, so a body origin's linear velocity is v + w x (x - c).
    """
    cvel = data.cvel[bodies]
    ang = cvel[:, 0:3]
    centre = data.subtree_com[model.body_rootid[bodies]]
    pos = data.xpos[bodies]
    lin = cvel[:, 3:6] + _cross(ang, pos - centre)
    com = data.subtree_com[bodies[0]]
    return BodyKin(pos.copy(), data.xmat[bodies].reshape(-1, 3, 3).copy(), lin, ang.copy(), com.copy())


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a x b for `[n, 3]` arrays: `np.cross`'s arithmetic (the same products and
    differences, so bit for bit its result) without its axis handling, which cost more than the
    products at this size (a fifth of the executor's step)."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


def _six(rot: np.ndarray) -> np.ndarray:
    """First two columns of rotation matrices `[..., 3, 3]` -> `[..., 6]`."""
    return np.concatenate([rot[..., :, 0], rot[..., :, 1]], axis=-1)


def agent_features(kin: BodyKin) -> np.ndarray:
    """o(X) `[7 + 15 (B - 1) + 6]`: root height, root tilt (6), then per non-root body its
    position (3) and rotation (6) in the root frame, root linear and angular velocity (3 + 3),
    per non-root body linear and angular velocity (3 + 3), all in the root frame."""
    root_rot = kin.rot[0]
    tilt = kin.heading_frame.T @ root_rot
    pos = (kin.pos[1:] - kin.pos[0]) @ root_rot
    rot = np.einsum("ji,bjk->bik", root_rot, kin.rot[1:])
    lin = kin.lin @ root_rot
    ang = kin.ang @ root_rot
    return np.concatenate([
        [kin.pos[0, 2]], _six(tilt), pos.reshape(-1), _six(rot).reshape(-1),
        lin[0], ang[0], lin[1:].reshape(-1), ang[1:].reshape(-1),
    ])


def target_root_pose(actual: BodyKin, target: BodyKin) -> np.ndarray:
    """y(X~; X) `[9]`: the target root's position (3) and rotation (6) in the actual root frame."""
    root_rot = actual.rot[0]
    return np.concatenate([(target.pos[0] - actual.pos[0]) @ root_rot, _six(root_rot.T @ target.rot[0])])


def observation(actual: BodyKin, targets: list[BodyKin], params: np.ndarray) -> np.ndarray:
    """s_t = [params, o(X_now), (o(X~_t+i), y(X~_t+i; X_now)) for i = 1..tau] as float32.

    params: the episode's parameter vector (the body's shape parameters; constant while the
    executor trains on one body), first, so shape variation can join without a new layout."""
    parts = [np.asarray(params, dtype=np.float64), agent_features(actual)]
    for target in targets:
        parts += [agent_features(target), target_root_pose(actual, target)]
    return np.concatenate(parts).astype(np.float32)
