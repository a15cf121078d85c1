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
from typing import Sequence

import mujoco
import numpy as np



@dataclass(frozen=True)
class BodyKin:
    """Bodies 1..nbody-1 of a model (index 0 here is the root): world positions `[..., B, 3]`
    (m), rotations `[..., B, 3, 3]`, linear velocities of the body origins `[..., B, 3]` (m/s)
    and angular velocities `[..., B, 3]` (rad/s), both in the world frame; and the centre of
    mass `[..., 3]`. The leading axes `...` (none for one state) batch states: every function
    here works on each state of a batch as on that state alone, with the same arithmetic, so
    a batch's results are its states' bit for bit (`ExecutorBatch` relies on it)."""

    pos: np.ndarray
    rot: np.ndarray
    lin: np.ndarray
    ang: np.ndarray
    com: np.ndarray

    @cached_property
    def heading_frame(self) -> np.ndarray:
        """The root's heading frame `[..., 3, 3]` (yaw only): the root rotation's twist about world
        z, atan2(R10 - R01, R00 + R11) (= 2 atan2(z, w) of its quaternion). For an upright root
        that is the yaw of its forward axis (x); unlike that yaw, it stays defined when the
        forward axis is vertical (a crawl, lying, a flip at +-90 degrees of pitch, where the
        axis's yaw swung on a few degrees of pitch), and is singular only upside down."""
        root = self.rot[..., 0, :, :]
        return yaw_matrices(np.arctan2(root[..., 1, 0] - root[..., 0, 1], root[..., 0, 0] + root[..., 1, 1]))

    def root_offsets(self) -> np.ndarray:
        """Non-root bodies relative to the root, in the world frame `[..., B - 1, 3]`."""
        return self.pos[..., 1:, :] - self.pos[..., :1, :]

    def relative_positions(self) -> np.ndarray:
        """Non-root bodies relative to the root, in the root's heading frame `[..., B - 1, 3]`."""
        return (self.pos[..., 1:, :] - self.pos[..., :1, :]) @ self.heading_frame

    def __getitem__(self, index) -> "BodyKin":
        """The states `index` picks along the leading axes."""
        return BodyKin(self.pos[index], self.rot[index], self.lin[index], self.ang[index], self.com[index])

    @staticmethod
    def stack(kins: Sequence["BodyKin"], axis: int = 0) -> "BodyKin":
        """`kins` stacked along a new leading axis."""
        if len(kins) == 1:  # NOTE: a view, not np.stack: the single environment is a batch of one every step
            k = kins[0]
            return BodyKin(*(np.expand_dims(x, axis) for x in (k.pos, k.rot, k.lin, k.ang, k.com)))
        return BodyKin(*(np.stack([getattr(k, f) for k in kins], axis=axis) for f in ("pos", "rot", "lin", "ang", "com")))


def yaw_matrices(yaw: np.ndarray) -> np.ndarray:
    """Rotations `[..., 3, 3]` about world z by `yaw` `[...]` rad (`yaw_matrix` over a batch)."""
    yaw = np.asarray(yaw, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros((*yaw.shape, 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1], out[..., 2, 2] = c, -s, s, c, 1.0
    return out


def kinematics_from_arrays(xpos: np.ndarray, xmat: np.ndarray, cvel: np.ndarray, subtree_com: np.ndarray,
                           rootid: np.ndarray, bodies: slice) -> BodyKin:
    """`BodyKin` `[..., B]` of `bodies` (root first) from MuJoCo's per-body arrays of one or more
    states `[..., nbody, ...]` (`xpos`, `xmat` `[..., nbody, 9]`, `cvel`, `subtree_com`) after
    `mj_kinematics`, `mj_comPos` and `mj_comVel`; `rootid`: `model.body_rootid`.

    NOTE: `cvel` is the spatial velocity (angular, linear) about the subtree centre of mass of
    each body's kinematic tree, so a body origin's linear velocity is v + w x (x - c).
    """
    cv = cvel[..., bodies, :]
    ang = cv[..., 0:3]
    centre = subtree_com[..., rootid[bodies], :]
    pos = xpos[..., bodies, :]
    lin = cv[..., 3:6] + _cross(ang, pos - centre)
    rot = xmat[..., bodies, :].reshape(*pos.shape[:-1], 3, 3)
    return BodyKin(pos.copy(), rot.copy(), lin, ang.copy(), subtree_com[..., bodies.start, :].copy())


def read_kinematics(model: mujoco.MjModel, data: mujoco.MjData, bodies: slice) -> BodyKin:
    """`BodyKin` of `bodies` (a slice of body ids, root first) from `data` after
    `mj_kinematics`, `mj_comPos` and `mj_comVel` (or `mj_forward`/`mj_step`)."""
    return kinematics_from_arrays(data.xpos, data.xmat, data.cvel, data.subtree_com, model.body_rootid, bodies)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a x b for `[..., 3]` arrays: `np.cross`'s arithmetic (the same products and
    differences, so bit for bit its result) without its axis handling, which cost more than the
    products at this size (a fifth of the executor's step)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _six(rot: np.ndarray) -> np.ndarray:
    """First two columns of rotation matrices `[..., 3, 3]` -> `[..., 6]`."""
    return np.concatenate([rot[..., :, 0], rot[..., :, 1]], axis=-1)


def _flat(x: np.ndarray, lead: tuple[int, ...]) -> np.ndarray:
    return x.reshape(*lead, -1)


def agent_features(kin: BodyKin) -> np.ndarray:
    """o(X) `[..., 7 + 15 (B - 1) + 6]`: root height, root tilt (6), then per non-root body its
    position (3) and rotation (6) in the root frame, root linear and angular velocity (3 + 3),
    per non-root body linear and angular velocity (3 + 3), all in the root frame."""
    lead = kin.com.shape[:-1]
    root_rot = kin.rot[..., 0, :, :]
    tilt = np.swapaxes(kin.heading_frame, -1, -2) @ root_rot
    pos = (kin.pos[..., 1:, :] - kin.pos[..., :1, :]) @ root_rot
    rot = np.einsum("...ji,...bjk->...bik", root_rot, kin.rot[..., 1:, :, :])
    lin = kin.lin @ root_rot
    ang = kin.ang @ root_rot
    return np.concatenate([
        kin.pos[..., 0, 2:3], _six(tilt), _flat(pos, lead), _flat(_six(rot), lead),
        lin[..., 0, :], ang[..., 0, :], _flat(lin[..., 1:, :], lead), _flat(ang[..., 1:, :], lead),
    ], axis=-1)


def target_root_pose(actual: BodyKin, target: BodyKin) -> np.ndarray:
    """y(X~; X) `[..., 9]`: the target root's position (3) and rotation (6) in the actual root
    frame (leading axes broadcast: one actual state against several targets)."""
    return root_pose_in(actual.pos[..., 0, :], actual.rot[..., 0, :, :], target.pos[..., 0, :], target.rot[..., 0, :, :])


def root_pose_in(root_pos: np.ndarray, root_rot: np.ndarray, pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """`target_root_pose` from the roots alone: the pose `pos` `[..., 3]`, `rot` `[..., 3, 3]`
    in the frame of the actual root `root_pos` `[..., 3]`, `root_rot` `[..., 3, 3]` -> `[..., 9]`."""
    offset = (pos - root_pos)[..., None, :] @ root_rot
    return np.concatenate([offset[..., 0, :], _six(np.swapaxes(root_rot, -1, -2) @ rot)], axis=-1)


def observation(actual: BodyKin, targets: BodyKin | list[BodyKin], params: np.ndarray) -> np.ndarray:
    """s_t = [params, o(X_now), (o(X~_t+i), y(X~_t+i; X_now)) for i = 1..tau] as float32 `[..., obs]`.

    actual `[...]`; targets `[..., tau]` (or a list of tau `BodyKin`s of one state); params
    `[..., P]`: the episode's parameter vector (the body's shape parameters; constant while the
    executor trains on one body), first, so shape variation can join without a new layout."""
    lead = actual.com.shape[:-1]
    if isinstance(targets, list):
        targets = BodyKin.stack(targets, axis=len(lead))
    return observation_of(actual, agent_features(targets), targets.pos[..., 0, :], targets.rot[..., 0, :, :], params)


def observation_of(actual: BodyKin, features: np.ndarray, root_pos: np.ndarray, root_rot: np.ndarray,
                   params: np.ndarray) -> np.ndarray:
    """`observation` from the targets' o(X~) `features` `[..., tau, F]` (`agent_features`, which
    depends on the frame alone: the executor computes it once per schedule row) and their roots'
    positions `[..., tau, 3]` and rotations `[..., tau, 3, 3]`."""
    lead = actual.com.shape[:-1]
    tau = features.shape[-2]
    at = (slice(None),) * len(lead) + (None,)
    pose = root_pose_in(actual.pos[at + (0,)], actual.rot[at + (0,)], root_pos, root_rot)
    per_target = np.concatenate([features, pose], axis=-1)
    params = np.asarray(params, dtype=np.float64)
    if params.shape[:-1] != lead:  # NOTE: broadcast_to only when needed: it cost 10 us, a tenth of a single step's features
        params = np.broadcast_to(params, (*lead, params.shape[-1]))
    parts = [params,
             agent_features(actual), per_target.reshape(*lead, tau * per_target.shape[-1])]
    return np.concatenate(parts, axis=-1).astype(np.float32)
