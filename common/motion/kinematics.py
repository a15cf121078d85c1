"""Clip-level kinematics: a pose at any time (slerp between frames), velocities, looping.

Everything here needs only the clip. Positions of joints, end effectors and the centre of
mass need a body, so they live in `common.motion.reference` (MuJoCo forward kinematics on a
character). Velocities use quaternion differences (`quat.angular_velocity_local`), never
differences of quaternion components.

Looping (DeepMimic's "wrap", Peng et al. 2018): past the end a looping clip starts again with
its root moved by the whole clip's horizontal displacement per cycle, so a walk keeps walking
forward instead of jumping back to its start.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from common.motion import quat
from common.motion.clip import Clip


@dataclass(frozen=True)
class Pose:
    """A clip pose at one time: root_pos (3,) m, root_quat (4,) wxyz, joint_qpos (Q,)."""

    root_pos: np.ndarray
    root_quat: np.ndarray
    joint_qpos: np.ndarray


@dataclass(frozen=True)
class Velocity:
    """Velocities at one time: root linear (3,) m/s world, root angular (3,) rad/s in the root
    frame (MuJoCo free-joint convention), joint (V,) rad/s: 3 per ball joint (child frame), 1 per
    hinge."""

    root_lin: np.ndarray
    root_ang: np.ndarray
    joint: np.ndarray


@functools.lru_cache(maxsize=256)
def _ball_columns(joint_types: tuple[str, ...]) -> np.ndarray:
    """(nb, 4) columns of the ball joints' quaternions in a packed joint_qpos."""
    cols, start = [], 0
    for kind in joint_types:
        if kind == "ball":
            cols.append(np.arange(start, start + 4))
            start += 4
        else:
            start += 1
    return np.array(cols, dtype=np.int64).reshape(-1, 4)


def interpolate(root_pos: np.ndarray, root_quat: np.ndarray, joint_qpos: np.ndarray, joint_types: tuple[str, ...],
                k0: np.ndarray, k1: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Blend frames k0 and k1 (int arrays (N,)) by alpha (N,) in [0, 1]: lerp positions and
    hinge angles, slerp quaternions. Returns (N, 3), (N, 4), (N, Q)."""
    a = alpha[:, None]
    pos = (1.0 - a) * root_pos[k0] + a * root_pos[k1]
    jq = (1.0 - a) * joint_qpos[k0] + a * joint_qpos[k1]
    cols = _ball_columns(tuple(joint_types))
    # One slerp call for the root and every ball joint: (N, 1 + nb, 4).
    q0 = np.concatenate([root_quat[k0][:, None], joint_qpos[k0][:, cols]], axis=1)
    q1 = np.concatenate([root_quat[k1][:, None], joint_qpos[k1][:, cols]], axis=1)
    q = quat.slerp(q0, q1, np.broadcast_to(a, q0.shape[:2]))
    jq[:, cols] = q[:, 1:]
    return pos, q[:, 0], jq


def resample_by_time(times_s: np.ndarray, root_pos: np.ndarray, root_quat: np.ndarray, joint_qpos: np.ndarray,
                     joint_types: tuple[str, ...], fps: float) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Resample keyframes at increasing times (T,) s onto a uniform grid of about `fps` Hz.

    The grid spans [0, times[-1]] exactly, so the rate is adjusted to (n - 1) / duration with
    n = round(duration * fps) + 1: a looping clip keeps its closing frame.
    Returns (fps_used, root_pos (n, 3), root_quat (n, 4), joint_qpos (n, Q)).
    """
    duration = float(times_s[-1] - times_s[0])
    n = max(2, int(round(duration * fps)) + 1)
    fps_used = (n - 1) / duration
    t = times_s[0] + np.arange(n) / fps_used
    t[-1] = times_s[-1]
    k1 = np.clip(np.searchsorted(times_s, t, side="right"), 1, len(times_s) - 1)
    k0 = k1 - 1
    alpha = np.clip((t - times_s[k0]) / (times_s[k1] - times_s[k0]), 0.0, 1.0)
    pos, rq, jq = interpolate(root_pos, root_quat, joint_qpos, joint_types, k0, k1, alpha)
    return fps_used, pos, rq, jq


def cycle_offset(clip: Clip) -> np.ndarray:
    """Horizontal root displacement (3,) m over one cycle (z = 0): last frame minus first.

    Translation only, as DeepMimic does: the clips' end heading differs from the start by
    capture noise (0.12 rad in the walk), and accumulating it would bend a straight walk
    into a circle.
    """
    d = clip.root_pos[-1] - clip.root_pos[0]
    return np.array([d[0], d[1], 0.0])


def _split_time(clip: Clip, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cycle index (N,) int, time within the clip (N,) s); non-looping clips clamp."""
    if clip.loop and clip.duration_s > 0:
        cycles = np.floor(t_s / clip.duration_s).astype(np.int64)
        return cycles, t_s - cycles * clip.duration_s
    return np.zeros(t_s.shape, np.int64), np.clip(t_s, 0.0, clip.duration_s)


def sample(clip: Clip, t_s: float | np.ndarray) -> Pose:
    """Pose at time(s) t_s (s; scalar or (N,)): slerp between neighbouring frames; a looping
    clip continues past its end with accumulated root displacement, others hold the last frame.
    Arrays get a leading (N,) axis when t_s is an array."""
    scalar = np.ndim(t_s) == 0
    t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
    cycles, local = _split_time(clip, t)
    f = local * clip.fps
    k0 = np.clip(np.floor(f).astype(np.int64), 0, clip.num_frames - 1)
    k1 = np.minimum(k0 + 1, clip.num_frames - 1)
    alpha = np.clip(f - k0, 0.0, 1.0)
    pos, rq, jq = interpolate(clip.root_pos, clip.root_quat, clip.joint_qpos, clip.joint_types, k0, k1, alpha)
    pos = pos + cycles[:, None] * cycle_offset(clip)
    if scalar:
        return Pose(pos[0], rq[0], jq[0])
    return Pose(pos, rq, jq)


def velocity(clip: Clip, t_s: float | np.ndarray, h_s: float | None = None) -> Velocity:
    """Velocities at time(s) t_s by a central difference over +-h_s (default half a frame).

    With h = half a frame the difference spans the slerp segment around t, so away from frame
    boundaries it is the exact derivative of the interpolated motion. Angular velocities come
    from quaternion differences q(t-h)^-1 q(t+h) as rotation vectors (local frames).
    """
    h = 0.5 / clip.fps if h_s is None else h_s
    t = np.asarray(t_s, dtype=np.float64)
    lo = t - h if clip.loop else np.clip(t - h, 0.0, max(clip.duration_s - 2 * h, 0.0))
    hi = lo + 2 * h
    a, b = sample(clip, lo), sample(clip, hi)
    lin = (b.root_pos - a.root_pos) / (2 * h)
    ang = quat.angular_velocity_local(a.root_quat, b.root_quat, 2 * h)
    parts = []
    for sl, kind in zip(clip.joint_slices(), clip.joint_types):
        if kind == "ball":
            parts.append(quat.angular_velocity_local(a.joint_qpos[..., sl], b.joint_qpos[..., sl], 2 * h))
        else:
            parts.append((b.joint_qpos[..., sl] - a.joint_qpos[..., sl]) / (2 * h))
    return Velocity(lin, ang, np.concatenate(parts, axis=-1))
