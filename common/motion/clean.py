"""Clean reference motions once, when they are prepared for a controller (issue 52 item 1).

Three things about the raw clips make them hard or impossible to track, whatever the policy:

- Keyframes too coarse or noisy for their derivatives: the DeepMimic flips are 16 fps keyframes
  interpolated linearly, the MASS clips carry mocap jitter (a knee swinging +-15 rad/s at 10 Hz),
  so the reference's joint velocity can change by more than the joint-velocity term's whole
  tolerance within one control step. `filter_qpos` resamples a clip onto a fine uniform grid
  and low-pass filters every track with a zero-phase Butterworth filter (`scipy.signal.filtfilt`,
  as is usual for mocap: Winter, "Biomechanics and Motor Control of Human Movement", 6-8 Hz
  cut-offs). The velocities are then the filtered tracks' derivatives wherever they are read
  (`CharacterMotion.qvel_at`: a difference of the filtered frames).
- Reference poses below the floor (DeepMimic's clips sink 11-33 mm on this body, up to 133 mm):
  `floor_offsets` lifts the root of every frame just enough that no geom of the character is
  below the floor (z = 0); frames above it are left where they are.
- Poses outside the joint ranges: not changed here (the executor widens its PD target ranges
  instead, `common.tasks.executor.env.widen_pd_ranges`); `reference_stats` counts them.

`clean_motion` applies the first two to a `CharacterMotion`; `reference_stats` measures a
motion the way the executor plays it (what `morphmimic motion check` prints before and after).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.signal import butter, filtfilt
from scipy.spatial.transform import Rotation

from common.motion.reference import CharacterMotion
from common.motion.root_height import lowest_points

FILTER_ORDER = 2
"""Order of the Butterworth filter; run forwards and backwards (filtfilt), the response is of
order 4 with no phase lag."""
FILTER_GRID_HZ = 120.0
"""Clips below this rate are resampled onto a uniform grid of about this rate before the filter:
filtering 16 fps keyframes in place would leave the linear interpolation's kinks (a velocity
jump at every keyframe) in the motion between them."""
PAD_S = 0.25
"""filtfilt's odd extension at either end of a clip (s, capped by the clip's length): the
filter's transient settles within it, so a clip's first and last frames keep their trend."""
WEIGHT_TOL = 1e-6
"""Filter weights below this (relative to the largest) are dropped when rotations are averaged."""


def _ball_and_hinge(model: mujoco.MjModel) -> tuple[list[int], list[int]]:
    """(qpos addresses of the ball joints' quaternions, of the hinge/slide angles), root excluded."""
    balls, scalars = [], []
    for j in range(1, model.njnt):
        adr = int(model.jnt_qposadr[j])
        kind = int(model.jnt_type[j])
        if kind == int(mujoco.mjtJoint.mjJNT_BALL):
            balls.append(adr)
        elif kind in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            scalars.append(adr)
        else:
            raise ValueError(f"joint {model.joint(j).name!r}: only the first joint may be free")
    return balls, scalars


def filter_matrix(n: int, fps: float, cutoff_hz: float) -> np.ndarray:
    """`[n, n]` the linear map of `filtfilt` (Butterworth low-pass, order `FILTER_ORDER`, odd
    extension of `PAD_S`) on a track of n samples at `fps`: filtered = M @ track. Each row sums to
    one (a constant passes unchanged)."""
    b, a = butter(FILTER_ORDER, cutoff_hz / (0.5 * fps))
    pad = min(n - 1, max(3 * FILTER_ORDER, int(round(PAD_S * fps))))
    return filtfilt(b, a, np.eye(n), axis=0, padtype="odd", padlen=pad)


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products a b of quaternions (w, x, y, z) `[..., 4]`."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def _qlog(q: np.ndarray) -> np.ndarray:
    """Rotation vectors `[..., 3]` (angle in [0, pi]) of unit quaternions `[..., 4]`."""
    q = np.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    return v * np.where(s > 1e-12, angle / np.maximum(s, 1e-12), 2.0)


def _qexp(r: np.ndarray) -> np.ndarray:
    """Unit quaternions `[..., 4]` of rotation vectors `[..., 3]`."""
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    half = 0.5 * angle
    k = np.where(angle > 1e-12, np.sin(half) / np.maximum(angle, 1e-12), 0.5)
    return np.concatenate([np.cos(half), r * k], axis=-1)


def _average_rotations(quats: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Quaternions `[n, J, 4]` (w, x, y, z) filtered by the weights `[n, n]` of a linear filter in
    the tangent space of each frame: q~_k = q_k exp(sum_j M_kj log(q_k^-1 q_j)). The rotation
    vectors are taken relative to the frame itself (a moving reference), so they stay far from
    the log map's wrap at pi however far a joint or the root turns over the clip; for
    Euclidean tracks the same formula is M @ x exactly (the rows sum to one). Weights below
    `WEIGHT_TOL` of the largest are left out (the band of the filter's impulse response)."""
    n = len(quats)
    q = quats / np.linalg.norm(quats, axis=-1, keepdims=True)
    inv = q * np.array([1.0, -1.0, -1.0, -1.0])
    band = np.abs(weights) > WEIGHT_TOL * np.abs(weights).max()
    rows_nz, cols_nz = np.nonzero(band)
    tangent = np.zeros((*q.shape[:-1], 3))
    k = np.arange(n)
    for d in np.unique(cols_nz - rows_nz):
        rows = k[max(0, -d): min(n, n - d)]
        w = weights[rows, rows + d]
        tangent[rows] += w[:, None, None] * _qlog(_qmul(inv[rows], q[rows + d]))
    out = _qmul(q, _qexp(tangent))
    out /= np.linalg.norm(out, axis=-1, keepdims=True)
    flip = np.sum(out * quats, axis=-1) < 0  # each track's sign kept as the input's (the same rotations)
    out[flip] *= -1.0
    return out


def filter_qpos(model: mujoco.MjModel, motion: CharacterMotion, cutoff_hz: float,
                grid_hz: float = FILTER_GRID_HZ) -> tuple[np.ndarray, float]:
    """(qpos frames `[n, nq]`, their rate in Hz) of `motion` resampled onto a uniform grid of at
    least `grid_hz` (the clip's own rate when higher; the duration is kept exactly) and low-pass
    filtered at `cutoff_hz` with zero phase (`filter_matrix`): root position and hinge angles
    directly, the root orientation and ball joints in the tangent space of each frame
    (`_average_rotations`). A cut-off at or above the grid's Nyquist rate leaves the resampled
    frames unfiltered."""
    duration = motion.duration_s
    fps_in = motion.frames.fps
    if duration <= 0:
        return motion.qpos_frames.copy(), fps_in
    n = max(2, int(math.ceil(duration * max(grid_hz, fps_in) - 1e-6)) + 1)
    fps = (n - 1) / duration
    q = np.atleast_2d(motion.qpos(np.linspace(0.0, duration, n)))
    if not 0 < cutoff_hz < 0.5 * fps or n < 4:
        return q, fps
    m = filter_matrix(n, fps, cutoff_hz)
    balls, scalars = _ball_and_hinge(model)
    out = q.copy()
    lin = [0, 1, 2, *scalars]
    out[:, lin] = m @ q[:, lin]
    cols = np.array([np.arange(3, 7)] + [np.arange(a, a + 4) for a in balls])
    out[:, cols] = _average_rotations(q[:, cols], m)
    return out, fps


def lowest_geom_heights(model: mujoco.MjModel, qpos_frames: np.ndarray) -> np.ndarray:
    """`[T]` height (m) of the lowest point of any of the character's geoms (those of bodies
    other than the world) in each frame (exact for primitive shapes, `lowest_points`)."""
    geoms = np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] > 0], dtype=np.int64)
    data = mujoco.MjData(model)
    frames = np.atleast_2d(qpos_frames)
    xpos, xmat = np.empty((len(frames), len(geoms), 3)), np.empty((len(frames), len(geoms), 9))
    for k, q in enumerate(frames):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        xpos[k], xmat[k] = data.geom_xpos[geoms], data.geom_xmat[geoms]
    return lowest_points(model, geoms, xpos, xmat).min(axis=1)


def floor_offsets(model: mujoco.MjModel, qpos_frames: np.ndarray) -> np.ndarray:
    """`[T]` vertical root lifts (m, >= 0): each frame lifted just enough that no geom of the
    character is below the floor (the rule "no geom below the floor on any frame"; a frame
    above the floor, a flight or one that floats, is left as it is). Per frame, as the
    executor's own start does it (`common.characters.morph.lift_out_of_floor`), so a start on
    any frame begins where the reference is."""
    return np.maximum(0.0, -lowest_geom_heights(model, qpos_frames))


def clean_motion(motion: CharacterMotion, cutoff_hz: float = 0.0, floor: bool = False) -> CharacterMotion:
    """`motion` with its tracks low-pass filtered at `cutoff_hz` (0: not filtered, the frames
    kept as they are; `filter_qpos`) and then, with `floor`, every frame lifted out of the floor
    (`floor_offsets`). The same motion object when neither is asked for. Velocities of the
    result (`qvel_at`) are differences of the cleaned frames: the cleaned tracks' derivatives."""
    if not cutoff_hz and not floor:
        return motion
    model = motion.model
    if cutoff_hz:
        q, fps = filter_qpos(model, motion, cutoff_hz)
    else:
        q, fps = motion.qpos_frames.copy(), motion.frames.fps
    if floor:
        q[:, 2] += floor_offsets(model, q)
    return CharacterMotion(motion.clip, model, q, motion.end_effector_bodies, fps=fps)


def dof_ranges(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(qpos address `[D]`, ball axis or -1 `[D]`, range `[D, 2]`) of every actuated DOF's PD
    target range (`actuator_ctrlrange`: the joint limit of a hinge, the target range of each
    ball-joint axis as a rotation-vector component)."""
    adr, axis, rng = [], [], []
    for a in range(model.nu):
        if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT or not model.actuator_ctrllimited[a]:
            continue
        j = int(model.actuator_trnid[a, 0])
        adr.append(int(model.jnt_qposadr[j]))
        axis.append(int(np.argmax(np.abs(model.actuator_gear[a, :3]))) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL else -1)
        rng.append(model.actuator_ctrlrange[a].copy())
    return np.array(adr, dtype=np.int64), np.array(axis, dtype=np.int64), np.array(rng).reshape(-1, 2)


def limit_excess(model: mujoco.MjModel, qpos_frames: np.ndarray, ranges: np.ndarray | None = None) -> np.ndarray:
    """`[T, D]` how far (rad, 0 inside) each actuated DOF of each frame is outside its PD target
    range (`dof_ranges`, or `ranges` `[D, 2]` in its order: e.g. widened ones)."""
    adr, axis, own = dof_ranges(model)
    ranges = own if ranges is None else np.asarray(ranges)
    q = np.atleast_2d(qpos_frames)
    values = np.empty((len(q), len(adr)))
    for d, (a, ax) in enumerate(zip(adr, axis)):
        if ax < 0:
            values[:, d] = q[:, a]
        else:
            values[:, d] = Rotation.from_quat(q[:, a:a + 4], scalar_first=True).as_rotvec()[:, ax]
    return np.maximum(0.0, np.maximum(ranges[:, 0] - values, values - ranges[:, 1]))


@dataclass(frozen=True)
class ReferenceStats:
    """What makes a reference hard to track, measured on a motion at the control rate."""

    limit_frames: float
    """Share of control steps with a DOF outside its PD target range (the character's own)."""
    limit_frames_widened: float
    """The same against the widened ranges (`widen_ranges`)."""
    velocity_jump_max: float
    """Largest one-step change of the joint velocities, sum over DOF of the squared change
    ((rad/s)^2): the joint-velocity term's error if the body kept the last step's velocity."""
    velocity_jump_share: float
    """Share of control steps whose velocity jump exceeds `tolerance`."""
    tolerance: float
    """The joint-velocity term's error at which it falls to alpha: ln(1 / alpha) / k ((rad/s)^2)."""
    sink_median_m: float
    """Median over control steps of the lowest geom's height (m; negative: below the floor)."""
    sink_worst_m: float
    """Lowest any geom goes (m)."""
    below_share: float
    """Share of control steps with a geom more than 1 mm below the floor."""

    def line(self) -> str:
        return (f"limits {100 * self.limit_frames:4.1f}% (widened {100 * self.limit_frames_widened:4.1f}%)  "
                f"vel jump max {self.velocity_jump_max:6.1f} (tol {self.tolerance:.1f}) over tol "
                f"{100 * self.velocity_jump_share:4.1f}%  floor median {1000 * self.sink_median_m:5.1f} "
                f"worst {1000 * self.sink_worst_m:6.1f} mm below {100 * self.below_share:3.0f}%")


def widen_ranges(model: mujoco.MjModel, ranges: np.ndarray | None = None) -> np.ndarray:
    """`[nu, 2]` the actuators' PD target ranges (`actuator_ctrlrange`) widened as MimicKit and PHC
    build their PD action bounds (Peng et al.'s MimicKit, Luo et al. 2023's PHC,
    `_build_pd_action_offset_scale`): a ball joint's axes all get +-1.2 x the largest bound of
    any of its axes (at most pi); a hinge's range 1.4 x its half-range either side of its
    middle (0.7 x its width). Actuators not on a joint keep theirs."""
    out = np.array(model.actuator_ctrlrange if ranges is None else ranges, dtype=np.float64, copy=True)
    by_joint: dict[int, list[int]] = {}
    for a in range(model.nu):
        if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT:
            by_joint.setdefault(int(model.actuator_trnid[a, 0]), []).append(a)
    for j, acts in by_joint.items():
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL:
            scale = min(1.2 * float(np.abs(out[acts]).max()), math.pi)
            out[acts] = [-scale, scale]
        else:
            for a in acts:
                mid, half = 0.5 * (out[a, 0] + out[a, 1]), 0.5 * (out[a, 1] - out[a, 0])
                out[a] = [mid - 1.4 * half, mid + 1.4 * half]
    return out


def reference_stats(motion: CharacterMotion, dt_s: float, tolerance: float, velocity_window: int = 1) -> ReferenceStats:
    """`ReferenceStats` of `motion` sampled on the control grid (every `dt_s` over its
    duration), its velocities as the executor's scheduler takes them (`qvel_at` over
    +-`velocity_window` steps)."""
    model = motion.model
    times = np.arange(0.0, motion.duration_s + 1e-9, dt_s)
    q = np.atleast_2d(motion.qpos(times))
    v = motion.qvel_at(times, velocity_window * dt_s)[:, 6:]
    jump = np.sum(np.diff(v, axis=0) ** 2, axis=-1) if len(v) > 1 else np.zeros(1)
    over = limit_excess(model, q) > 1e-6
    wide = widen_ranges(model)
    acts = [a for a in range(model.nu) if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT and model.actuator_ctrllimited[a]]
    over_wide = limit_excess(model, q, wide[acts]) > 1e-6
    low = lowest_geom_heights(model, q)
    return ReferenceStats(float(over.any(axis=1).mean()), float(over_wide.any(axis=1).mean()), float(jump.max()),
                          float(np.mean(jump > tolerance)), float(tolerance), float(np.median(low)), float(low.min()),
                          float(np.mean(low < -0.001)))
