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

import numpy as np

from common.characters import base_character
from common.motion import MotionLibrary
from common.motion.clip import Clip
from common.motion.kinematics import sample
from common.motion.reference import CharacterMotion
from common.motion.retarget import ContactPhases, RetargetConfig, contact_phases, play_on

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
