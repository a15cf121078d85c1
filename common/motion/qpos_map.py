"""The one place where a clip frame becomes MuJoCo qpos for a particular character model.

A clip stores local joint rotations in world-aligned rest frames (see `clip.py`). An MJCF may
give its bodies any rest orientation W_b (the body's world orientation at qpos0, root at its
default). Then, for the body b a joint moves,
    ball joint qpos   = W_b^-1 Q_b W_b                       (conjugation into the body frame)
    free root qpos    = Q_root W_root
    hinge joint qpos  = twist of Q_b about the hinge's world rest axis W_b a_b
    3 hinges (x,y,z)  = Euler angles of W_b^-1 Q_b W_b in the hinges' order
which keeps every body's world orientation equal to Q_root Q_1 ... Q_b W_b, whatever W_b is.
Clip joints are matched to model joints by joint name, else by the name of the body they move.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from common.motion import quat
from common.motion.clip import Clip
from common.motion.errors import ClipError


@dataclass(frozen=True)
class _Target:
    kind: str  # "ball", "hinge", "euler"
    clip_cols: slice
    qpos_adr: int
    w_body: np.ndarray  # (4,) rest world orientation of the moved body
    axis: np.ndarray  # (3,) hinge world rest axis (hinge) or clip hinge axis
    clip_kind: str
    euler_seq: str = ""


class QposMap:
    """Maps clip frames to qpos (nq,) of `model`; built once per (clip joint layout, model)."""

    def __init__(self, clip: Clip, model: mujoco.MjModel) -> None:
        self.model = model
        if model.njnt == 0 or model.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE:
            raise ClipError("the character's first joint must be a free root joint", path=clip.name)
        self.root_body = int(model.jnt_bodyid[0])
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        self.w_root = data.xquat[self.root_body].copy()
        targets, used = [], set()
        for j, (name, kind, cols) in enumerate(zip(clip.joint_names, clip.joint_types, clip.joint_slices())):
            jids = self._joints_for(name)
            if not jids:
                raise ClipError(f"the character has no joint or body named {name!r}; its joints: "
                                f"{', '.join(model.joint(i).name for i in range(1, model.njnt))}", path=clip.name, joint=name)
            used.update(jids)
            body = int(model.jnt_bodyid[jids[0]])
            w = data.xquat[body].copy()
            types = [int(model.jnt_type[i]) for i in jids]
            adr = int(model.jnt_qposadr[jids[0]])
            if types == [mujoco.mjtJoint.mjJNT_BALL]:
                if kind != "ball":
                    raise ClipError("clip has a hinge here but the character a ball joint", path=clip.name, joint=name)
                targets.append(_Target("ball", cols, adr, w, np.zeros(3), kind))
            elif types == [mujoco.mjtJoint.mjJNT_HINGE]:
                axis = Rotation.from_quat(w, scalar_first=True).apply(model.jnt_axis[jids[0]])
                targets.append(_Target("hinge", cols, adr, w, axis, kind))
            elif types == [mujoco.mjtJoint.mjJNT_HINGE] * 3 and kind == "ball":
                seq = "".join("XYZ"[int(np.argmax(np.abs(model.jnt_axis[i])))] for i in jids)
                targets.append(_Target("euler", cols, adr, w, np.zeros(3), kind, seq))
            else:
                raise ClipError(f"cannot drive joints of types {types} from a clip {kind} joint", path=clip.name, joint=name)
        self.targets = tuple(targets)
        self.clip_hinge_axes = clip.hinge_axes
        self.undriven = tuple(model.joint(i).name for i in range(1, model.njnt) if i not in used)

    def _joints_for(self, name: str) -> list[int]:
        m = self.model
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid >= 1:
            return [jid]
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
        if bid < 1:
            return []
        start, count = int(m.body_jntadr[bid]), int(m.body_jntnum[bid])
        return list(range(start, start + count))

    def to_qpos(self, root_pos: np.ndarray, root_quat: np.ndarray, joint_qpos: np.ndarray, clip_hinge_axes: np.ndarray | None = None) -> np.ndarray:
        """qpos (N, nq) from clip arrays (N, 3), (N, 4), (N, Q); undriven joints stay at qpos0."""
        axes = self.clip_hinge_axes if clip_hinge_axes is None else clip_hinge_axes
        n = root_pos.shape[0]
        qpos = np.tile(self.model.qpos0, (n, 1))
        root_adr = int(self.model.jnt_qposadr[0])
        qpos[:, root_adr:root_adr + 3] = root_pos
        qpos[:, root_adr + 3:root_adr + 7] = quat.multiply(root_quat, self.w_root)
        for j, t in enumerate(self.targets):
            q_clip = joint_qpos[:, t.clip_cols]
            if t.clip_kind == "hinge":
                # A clip hinge is a rotation by its angle about its own axis.
                half = q_clip[:, 0] / 2.0
                q_clip = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * axes[j]], axis=1)
            if t.kind == "hinge":
                qpos[:, t.qpos_adr] = 2.0 * np.arctan2(q_clip[:, 1:] @ t.axis, q_clip[:, 0])
                continue
            local = quat.multiply(quat.multiply(quat.conjugate(t.w_body), q_clip), t.w_body)
            if t.kind == "ball":
                qpos[:, t.qpos_adr:t.qpos_adr + 4] = local
            else:
                qpos[:, t.qpos_adr:t.qpos_adr + 3] = Rotation.from_quat(local, scalar_first=True).as_euler(t.euler_seq)
        return qpos
