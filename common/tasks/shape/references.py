"""Reference motions for the shape tasks: which clip each character follows, made loopable and
cheap to retarget, and played on a shaped character (issue 4's retargeting).

- The lower-body biped follows the MASS walk with its upper-body joints dropped (the library
  refuses a biped clip on the lower biped: the joint sets differ).
- `mass/walk` is one gait cycle that does not close exactly (up to 0.27 rad at the seam): the
  mismatch is spread linearly over the cycle so the clip loops for a 30 s episode.
- Clips are resampled to `RESAMPLE_FPS` before retargeting: retargeting runs a foot solve per
  frame, and every episode of a new shape pays it, so fewer frames mean faster resets.
- Swimmers are played without retargeting (`retarget.play_on` does that for legless bodies;
  `MotionLibrary.play` would fail on their contact phases).
"""

from __future__ import annotations

import functools
from typing import Callable

import mujoco
import numpy as np

from common.characters import base_character
from common.motion import MotionLibrary
from common.motion.clip import Clip
from common.motion.kinematics import sample
from common.motion.reference import CharacterMotion
from common.motion.retarget import ContactPhases, RetargetConfig, contact_phases, play_on
from common.tasks.observations import JointLayout

DEFAULT_CLIPS = {
    "lower_biped": "mass/walk",
    "biped": "mass/walk",
    "quadruped": "procedural/quadruped",
    "fish": "procedural/fish",
    "manta": "procedural/manta",
}
"""The clip each character task follows unless `TaskConfig.clip_id` says otherwise."""
RESAMPLE_FPS = 60.0
"""Frames per second of the clip retargeted per episode (twice the 30 Hz control rate)."""


@functools.lru_cache(maxsize=None)
def _library() -> MotionLibrary:
    return MotionLibrary()


def close_loop(clip: Clip) -> Clip:
    """Spread the seam mismatch (first frame minus last) linearly over the clip, joint qpos and
    root height and orientation, and mark it looping. Quaternions are renormalized."""
    n = clip.num_frames
    ramp = (np.arange(n) / max(1, n - 1))[:, None]
    jq = clip.joint_qpos + ramp * (clip.joint_qpos[0] - clip.joint_qpos[-1])
    for kind, sl in zip(clip.joint_types, clip.joint_slices()):
        if kind == "ball":
            q = jq[:, sl]
            q *= np.sign(np.sum(q * clip.joint_qpos[0, sl], axis=1, keepdims=True) + 1e-12)
            jq[:, sl] = q / np.linalg.norm(q, axis=1, keepdims=True)
    rq = clip.root_quat + ramp * (clip.root_quat[0] - clip.root_quat[-1])
    rq /= np.linalg.norm(rq, axis=1, keepdims=True)
    rp = clip.root_pos.copy()
    rp[:, 2] += ramp[:, 0] * (clip.root_pos[0, 2] - clip.root_pos[-1, 2])
    return clip.with_(joint_qpos=jq, root_quat=rq, root_pos=rp, loop=True)


def subset_joints(clip: Clip, joint_names: list[str], character: str) -> Clip:
    """The clip restricted to the joints the character has (by name), relabelled for it."""
    keep = [i for i, name in enumerate(clip.joint_names) if name in joint_names]
    slices = clip.joint_slices()
    cols = np.concatenate([clip.joint_qpos[:, slices[i]] for i in keep], axis=1)
    return clip.with_(joint_names=tuple(clip.joint_names[i] for i in keep),
                      joint_types=tuple(clip.joint_types[i] for i in keep), joint_qpos=cols,
                      hinge_axes=np.asarray(clip.hinge_axes)[keep], character=character)


def resample(clip: Clip, fps: float) -> Clip:
    """The clip at `fps` (slerp between frames; a looping clip keeps its closing frame)."""
    n = max(2, int(round(clip.duration_s * fps)) + 1)
    t = np.linspace(0.0, clip.duration_s, n)
    p = sample(clip, t)
    return clip.with_(root_pos=p.root_pos, root_quat=p.root_quat, joint_qpos=p.joint_qpos, fps=(n - 1) / clip.duration_s)


@functools.lru_cache(maxsize=None)
def task_clip(preset: str, clip_id: str, timestep_s: float) -> tuple[Clip, ContactPhases | None]:
    """The prepared clip of `clip_id` for `preset` and its contact phases on the base character
    (None for swimmers). Cached per process: every episode reuses them."""
    base = base_character(preset, timestep_s)
    clip = _library().clip(clip_id)
    if clip.character and clip.character != preset:
        clip = subset_joints(clip, base.joint_names, preset)
    if not clip.loop:
        clip = close_loop(clip)
    if clip.fps > RESAMPLE_FPS * 1.01:
        clip = resample(clip, RESAMPLE_FPS)
    contacts = contact_phases(clip, base.model, base.foot_geoms) if base.foot_geoms else None
    return clip, contacts


def play(character, clip_id: str, timestep_s: float, retarget: RetargetConfig = RetargetConfig()) -> CharacterMotion:
    """The task clip retargeted onto a shaped character (see module docstring)."""
    clip, contacts = task_clip(character.preset, clip_id, timestep_s)
    return play_on(clip, character, base_character(character.preset, timestep_s), retarget, contacts)


def cycle_velocity(clip: Clip) -> np.ndarray:
    """Mean horizontal root velocity `[2]` m/s of one cycle of the clip (on its base body)."""
    return (clip.root_pos[-1, :2] - clip.root_pos[0, :2]) / max(clip.duration_s, 1e-9)


class GridReference:
    """One episode's reference on its control grid: row r holds the reference at episode time
    (r - 1) dt (row 0 is step -1, for the centred velocity at step 0), everything the state,
    the reward, the termination and the PD target of Won & Lee 2019 (METHOD.md A) read from it,
    computed once per row. The rows are filled `chunk` at a time as the episode reaches them
    (episodes often end long before the horizon early in training).

    Columns of `rows` `[T, width]` (`column(name)`): "q" qpos `[nq]` (heading and speed applied
    by `sample`), "j" the joint vector `[nu]` (`JointLayout.to_vector`), "qvel" `[nv]` the
    centred difference `mj_differentiatePos` of rows r - 1 and r + 1 over 2 dt, "ee" the end
    effectors `[3E]` relative to the reference root in its heading frame (`mj_kinematics` of the
    row on the motion's own MjData, as `CharacterMotion.positions`), "facing" `[2]` the horizontal facing
    of the root (first column of its heading frame) and "rmat" the root orientation `[9]`
    (row-major rotation matrix). "qvel" of a row is there once row r + 1 is.
    """

    def __init__(self, sample: Callable[[np.ndarray], np.ndarray], motion: CharacterMotion, model: mujoco.MjModel,
                 layout: JointLayout, ee_ids: np.ndarray, dt_s: float, chunk: int):
        self.sample, self.motion, self.model, self.layout = sample, motion, model, layout
        self.ee_ids, self.dt, self.chunk = ee_ids, dt_s, chunk
        sizes = {"q": model.nq, "j": model.nu, "qvel": model.nv, "ee": 3 * len(ee_ids), "facing": 2, "rmat": 9}
        self.slices: dict[str, slice] = {}
        start = 0
        for name, size in sizes.items():
            self.slices[name] = slice(start, start + size)
            start += size
        self.width = start
        self.rows = np.zeros((0, self.width))
        """`[T, width]` the rows filled so far."""

    def column(self, name: str) -> np.ndarray:
        """The rows filled so far of one column `[T, size]` (a view)."""
        return self.rows[:, self.slices[name]]

    def ensure(self, need: int) -> None:
        """Fill rows up to at least `need` (exclusive), a chunk at a time."""
        start = len(self.rows)
        if need <= start:
            return
        stop = max(need, start + self.chunk)
        q = self.sample((np.arange(start, stop) - 1) * self.dt)
        new = np.zeros((stop - start, self.width))
        new[:, self.slices["q"]] = q
        new[:, self.slices["j"]] = self.layout.to_vector(q)
        # The end effectors by forward kinematics row by row (`CharacterMotion.positions`), the
        # rest as arrays over the chunk: the same float operations as `quat_to_mat`, `heading`
        # and `yaw_matrix` on each row.
        rot = new[:, self.slices["rmat"]]
        body = np.zeros((len(q), len(self.ee_ids), 3))
        model, data = self.motion.model, self.motion.data
        for r, qpos in enumerate(q):
            mujoco.mju_quat2Mat(rot[r], qpos[3:7])
            data.qpos[:] = qpos
            mujoco.mj_kinematics(model, data)
            body[r] = data.xpos[self.ee_ids]
        yaw = np.arctan2(rot[:, 3], rot[:, 0])
        c, s = np.cos(yaw), np.sin(yaw)
        frame = np.zeros((len(q), 3, 3))
        frame[:, 0, 0], frame[:, 0, 1], frame[:, 1, 0], frame[:, 1, 1], frame[:, 2, 2] = c, -s, s, c, 1.0
        new[:, self.slices["ee"]] = np.matmul(body - q[:, None, 0:3], frame).reshape(len(q), -1)
        new[:, self.slices["facing"]] = frame[:, :2, 0]
        self.rows = np.concatenate([self.rows, new]) if start else new
        qs, qv = self.column("q"), self.column("qvel")
        for r in range(max(1, start - 1), stop - 1):
            mujoco.mj_differentiatePos(self.model, qv[r], 2.0 * self.dt, qs[r - 1], qs[r + 1])
