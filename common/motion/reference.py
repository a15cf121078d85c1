"""A clip played on one character: reference qpos, qvel, body and end-effector positions and
the centre of mass at any time (what the imitation reward and the observation need).

Won & Lee 2019 (METHOD.md A): reference postures at t, t + 0.5 s, t + 1.0 s, joint velocities
and end-effector positions; UniCon (METHOD.md B): all joints' positions and the root pose.
Positions come from MuJoCo's own forward kinematics (`mj_kinematics`, `mj_comPos`) on the
character model, so they agree with the simulated body. Velocities are MuJoCo's
`mj_differentiatePos` (quaternion differences on free and ball joints) over +-half a frame.

Frames are mapped to qpos once (`QposMap`, plus retargeting, see `retarget.py`) and
interpolated in qpos space: positions and hinge angles linearly, free and ball quaternions by
slerp; a looping clip continues with its root displaced by one cycle's displacement per loop.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import mujoco
import numpy as np

from common.motion import kinematics
from common.motion.clip import Clip
from common.motion.qpos_map import QposMap


@dataclass(frozen=True)
class ReferenceState:
    """The reference at one time. World frame, Z up, metres, radians.

    qpos (nq,), qvel (nv,) MuJoCo layout; body_pos (nbody, 3) body-frame origins (index 0 is
    the world); end_effectors (E, 3) in `CharacterMotion.end_effector_bodies` order;
    com (3,) and com_vel (3,) m/s of the whole character.
    """

    time_s: float
    qpos: np.ndarray
    qvel: np.ndarray
    body_pos: np.ndarray
    end_effectors: np.ndarray
    com: np.ndarray
    com_vel: np.ndarray


def model_clip(clip: Clip, model: mujoco.MjModel, qpos: np.ndarray, fps: float | None = None) -> Clip:
    """Wrap qpos frames (T, nq) of `model` as a Clip whose joints are the model's own
    (identity rest frames), so `kinematics.sample` interpolates them directly; at `fps` (the
    clip's own rate when None: frames resampled by `clean.filter_qpos` have another)."""
    names, types = [], []
    for j in range(1, model.njnt):
        kind = int(model.jnt_type[j])
        if kind == mujoco.mjtJoint.mjJNT_BALL:
            types.append("ball")
        elif kind in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            types.append("hinge")
        else:
            raise ValueError(f"joint {model.joint(j).name!r}: only the first joint may be free")
        names.append(model.joint(j).name)
    return Clip(name=clip.name, fps=clip.fps if fps is None else float(fps), root_pos=qpos[:, 0:3], root_quat=qpos[:, 3:7], joint_names=tuple(names),
                joint_types=tuple(types), joint_qpos=qpos[:, 7:], hinge_axes=np.zeros((len(names), 3)), loop=clip.loop,
                label=clip.label, character=clip.character, source=clip.source, license=clip.license, extra=clip.extra)


class CharacterMotion:
    """A clip on a character model (one shape). Build with `from_qpos` or `retarget.play_on`.

    NOTE: holds one MjData for its own kinematics; not thread-safe, make one per environment.
    """

    def __init__(self, clip: Clip, model: mujoco.MjModel, qpos_frames: np.ndarray, end_effector_bodies: tuple[str, ...] = (),
                 fps: float | None = None) -> None:
        """`qpos_frames` `[T, nq]` uniform in time at `fps` (the clip's own rate when None); `clip`
        gives the name, label and loop flag."""
        if model.jnt_qposadr[0] != 0 or model.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE:
            raise ValueError("the character's first joint must be the free root at qpos[0:7]")
        self.clip = clip
        self.model = model
        self.frames = model_clip(clip, model, qpos_frames, fps)
        self.end_effector_bodies = tuple(end_effector_bodies)
        self._ee_ids = np.array([model.body(b).id for b in end_effector_bodies], dtype=np.int64)
        self._root_body = int(model.jnt_bodyid[0])

    @classmethod
    def from_clip(cls, clip: Clip, model: mujoco.MjModel, end_effector_bodies: tuple[str, ...] = ()) -> "CharacterMotion":
        """Play the clip as it is (no retargeting) on `model`."""
        qpos = QposMap(clip, model).to_qpos(clip.root_pos, clip.root_quat, clip.joint_qpos)
        return cls(clip, model, qpos, end_effector_bodies)

    @functools.cached_property
    def data(self) -> mujoco.MjData:
        """The MjData of the motion's own kinematics (`positions`), made on first use: about 0.5 MB
        on the humanoid, which a library of clips that only samples qpos never needs."""
        return mujoco.MjData(self.model)

    @property
    def duration_s(self) -> float:
        return self.frames.duration_s

    @property
    def qpos_frames(self) -> np.ndarray:
        """(T, nq) the clip's frames as qpos of this character."""
        f = self.frames
        return np.concatenate([f.root_pos, f.root_quat, f.joint_qpos], axis=1)

    def qpos(self, t_s: float | np.ndarray) -> np.ndarray:
        """Reference qpos (nq,) at t_s seconds, or (N, nq) for an array of times."""
        p = kinematics.sample(self.frames, t_s)
        return np.concatenate([p.root_pos, p.root_quat, p.joint_qpos], axis=-1)

    def qvel(self, t_s: float, h_s: float | None = None) -> np.ndarray:
        """Reference qvel (nv,) at t_s: `mj_differentiatePos` of qpos(t - h) -> qpos(t + h)."""
        return self.qvel_at(np.array([t_s], dtype=np.float64), h_s)[0]

    def qvel_at(self, t_s: np.ndarray, h_s: float | None = None) -> np.ndarray:
        """Reference qvel `[N, nv]` (per second of clip time) at the times `t_s` `[N]`: the
        difference of qpos(t - h) -> qpos(t + h). A clip that does not loop holds its first and
        last frames outside its span, so there the window slides inside the clip (a one-sided
        difference at the ends, and the end's velocity for times beyond them): a centred window
        would see half the motion at the first and last frames."""
        h = 0.5 / self.frames.fps if h_s is None else float(h_s)
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        lo = t - h if self.frames.loop else np.clip(t - h, 0.0, max(self.duration_s - 2 * h, 0.0))
        span = np.full(len(t), 2 * h) if self.frames.loop else np.minimum(lo + 2 * h, self.duration_s) - lo
        qa, qb = np.atleast_2d(self.qpos(lo)), np.atleast_2d(self.qpos(lo + span))
        out = np.zeros((len(t), self.model.nv))
        for i in range(len(t)):
            if span[i] > 0:
                mujoco.mj_differentiatePos(self.model, out[i], float(span[i]), qa[i], qb[i])
        return out

    def positions(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(body_pos (nbody, 3), com (3,)) of a pose by MuJoCo forward kinematics."""
        self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        return self.data.xpos.copy(), self.data.subtree_com[self._root_body].copy()

    def state(self, t_s: float) -> ReferenceState:
        """Everything the task needs about the reference at time t_s (see ReferenceState)."""
        h = 0.5 / self.frames.fps
        qpos = self.qpos(t_s)
        body_pos, com = self.positions(qpos)
        _, com_a = self.positions(self.qpos(t_s - h))
        _, com_b = self.positions(self.qpos(t_s + h))
        return ReferenceState(float(t_s), qpos, self.qvel(t_s), body_pos, body_pos[self._ee_ids], com, (com_b - com_a) / (2 * h))
