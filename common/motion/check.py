"""Per-clip sanity report on a character: feet against the floor, root bob, joint limits, rate, length.

What a user wants to know before training on a clip (issue 4): does it fit the body (feet
neither sink nor float once retargeted), does it ask joints for angles the character cannot
reach, and is its rate and length sensible. Float is measured twice: on the frames found in
contact (`stance_float_m`), and on every frame (`lowest_max_m`, `lowest_mean_m`: the lower
foot's height, which a missed contact cannot hide; flights and flips raise it legitimately).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from common.motion.reference import CharacterMotion
from common.motion.root_height import foot_heights, lowest_points

AIRBORNE_M = 0.02
"""Both feet higher than this: the frame counts as airborne (jump, flip) or floating."""


@dataclass(frozen=True)
class ClipReport:
    """Findings for one clip on one character. Lengths in m, angles in rad."""

    name: str
    character: str
    fps: float
    frames: int
    duration_s: float
    loop: bool
    penetration_m: float
    """Deepest a foot goes below the floor (0 if never)."""
    stance_float_m: float
    """Highest the lower foot gets while at least one foot is in a contact phase (0 if never)."""
    airborne_frac: float
    """Share of frames with both feet above AIRBORNE_M."""
    limit_violations: int
    """Number of (frame, DOF) pairs outside the character's joint range / PD target range."""
    worst_limit: str
    """'joint: excess rad' of the worst violation, or '-'."""
    root_range_m: float = 0.0
    """How far the root's height ranges over the clip (`root_bob`)."""
    root_step_m: float = 0.0
    """The largest change of the root's height between two frames (`root_bob`)."""
    lowest_max_m: float = 0.0
    """Over EVERY frame, not only contact phases: the largest height of the lower foot's lowest
    point above the floor (a walk planted on the floor keeps this near 0; flights raise it)."""
    lowest_mean_m: float = 0.0
    """Over every frame: the mean height of the lower foot's lowest point above the floor
    (negative when it is mostly below)."""

    def feet(self) -> str:
        """The foot figures in cm: penetration, float in contact phases, the lower foot over every frame."""
        return (f"pen {100 * self.penetration_m:4.1f} float {100 * self.stance_float_m:4.1f} "
                f"low max {100 * self.lowest_max_m:5.1f} mean {100 * self.lowest_mean_m:4.1f}")

    def line(self, raw: "ClipReport | None" = None) -> str:
        """One human-readable line (what `morphmimic motion check` prints); with `raw` (the
        clip played as recorded, or for a cross-skeleton clip its source copied naively) its
        foot figures come first, then these (retargeted)."""
        feet = f"{self.feet()} cm"
        if raw is not None:
            feet = f"raw {raw.feet()} -> {feet}"
        return (f"{self.name:<24} {self.character:<8} {self.fps:5.1f} Hz {self.frames:4d} fr {self.duration_s:5.2f} s "
                f"{'loop' if self.loop else 'once'}  {feet}  air {100 * self.airborne_frac:3.0f}%  "
                f"root {100 * self.root_range_m:4.1f} cm step {1000 * self.root_step_m:3.0f} mm  "
                f"limits {self.limit_violations:4d} ({self.worst_limit})")


def root_bob(qpos_frames: np.ndarray) -> tuple[float, float]:
    """(range, largest step) of the root's height over a clip's qpos frames `[T, nq]`, in m.

    A walker's root rises and falls a few cm per cycle; a much larger range on a shaped body,
    or a step of centimetres between two frames, means the retargeting moved the root where
    the clip does not (a quadruped with unequal leg pairs under the "contact_set" root-height
    rule: the root drops when the shorter pair takes over). The reference then asks the body
    for a vertical jerk no controller can follow, and such shapes fall far more often (the
    table by this range in `morphmimic evaluate`'s summary)."""
    z = np.asarray(qpos_frames, dtype=np.float64)[:, 2]
    step = float(np.abs(np.diff(z)).max()) if len(z) > 1 else 0.0
    return float(np.ptp(z)), step


def body_clearance(model: mujoco.MjModel, qpos_frames: np.ndarray, bodies: np.ndarray) -> tuple[float, str]:
    """(lowest height m, body name) that any geom of `bodies` (ids) reaches over a clip's qpos
    frames `[T, nq]`: how close the reference itself brings a body that may not touch the floor
    to it. Under the fall rule (a floor contact of any body but the feet, Won & Lee 2019) a
    reference whose shin reaches the floor asks for a fall: on the lower biped's 300 evaluation
    shapes, on MASS's shank box, the 8 whose retargeted walk brought a shin within 5 mm of the floor
    all fell, 7 of them within 1 s; the slimmer box (`lower_biped.shank_box`) keeps every shank 16 mm
    clear (`morphmimic evaluate` tables falls by this clearance)."""
    geoms = np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] in set(int(b) for b in bodies)], dtype=np.int64)
    if len(geoms) == 0 or len(qpos_frames) == 0:
        return float("inf"), ""
    data = mujoco.MjData(model)
    low = np.empty((len(qpos_frames), len(geoms)))
    for k, q in enumerate(np.asarray(qpos_frames)):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        low[k] = lowest_points(model, geoms, data.geom_xpos[geoms][None], data.geom_xmat[geoms][None])[0]
    k, g = np.unravel_index(int(np.argmin(low)), low.shape)
    return float(low[k, g]), model.body(int(model.geom_bodyid[geoms[g]])).name


def _dof_ranges(model: mujoco.MjModel) -> list[tuple[str, int, int, float, float]]:
    """(name, joint id, axis or -1, lo, hi): hinge limits, and the PD target range of each
    ball-joint axis (the characters give ball joints no limit, only `ctrlrange`)."""
    out = []
    for j in range(1, model.njnt):
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE and model.jnt_limited[j]:
            out.append((model.joint(j).name, j, -1, *model.jnt_range[j]))
    for a in range(model.nu):
        if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT or not model.actuator_ctrllimited[a]:
            continue
        j = int(model.actuator_trnid[a, 0])
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL:
            axis = int(np.argmax(np.abs(model.actuator_gear[a, :3])))
            out.append((f"{model.joint(j).name}.{'xyz'[axis]}", j, axis, *model.actuator_ctrlrange[a]))
    return out


def check_motion(motion: CharacterMotion, foot_geoms: tuple[str, ...], contact_flags: np.ndarray | None = None) -> ClipReport:
    """Report on a clip played on a character (see ClipReport)."""
    model, clip = motion.model, motion.clip
    qpos = motion.qpos_frames
    if foot_geoms:
        h, _ = foot_heights(model, qpos, foot_geoms)
        lower = h.min(axis=1)
        penetration = max(0.0, -float(h.min()))
        stance = contact_flags.any(axis=1) if contact_flags is not None else np.ones(len(h), bool)
        stance_float = max(0.0, float(lower[stance].max())) if stance.any() else 0.0
        airborne = float(np.mean(lower > AIRBORNE_M))
        lowest_max, lowest_mean = max(0.0, float(lower.max())), float(lower.mean())
    else:
        penetration = stance_float = airborne = lowest_max = lowest_mean = 0.0
    count, worst, worst_name = 0, 0.0, "-"

    for name, j, axis, lo, hi in _dof_ranges(model):
        adr = model.jnt_qposadr[j]
        if axis < 0:
            values = qpos[:, adr]
        else:
            values = Rotation.from_quat(qpos[:, adr:adr + 4], scalar_first=True).as_rotvec()[:, axis]
        excess = np.maximum(lo - values, values - hi)
        count += int(np.sum(excess > 1e-6))
        if excess.max() > worst:
            worst, worst_name = float(excess.max()), f"{name}: +{excess.max():.2f}"
    return ClipReport(clip.name, clip.character, clip.fps, clip.num_frames, clip.duration_s, clip.loop,
                      penetration, stance_float, airborne, count, worst_name, *root_bob(qpos),
                      lowest_max_m=lowest_max, lowest_mean_m=lowest_mean)
