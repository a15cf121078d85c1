"""Play a clip on a character of any shape with the feet on the floor.

Won & Lee 2019 (METHOD.md A) retarget the reference to each body shape: a shape changes limb
lengths, so the clip's root height and root speed no longer fit the legs, and feet would
sink into or float above the ground. Joint rotations carry over unchanged (the same motion,
another body); what changes is:
1. root velocity and height scaled by the leg-length ratio r = mean leg / base mean leg
   (the horizontal path is scaled about the first frame, so strides fit the legs);
2. a per-frame vertical root offset that puts the *highest* foot in contact on the floor
   (contact phases come from the clip on the base character); between contact phases the
   offset is interpolated in time, which keeps jumps and flips' flight arcs. With unequal
   legs the highest foot of one contact set can sit far above that of the next (a quadruped's
   two diagonal pairs), and the root would drop by the difference within a frame or two;
   `RetargetConfig.root_height = "foot_tracks"` follows each foot's in-contact height through
   its own swing instead, so the offset is continuous (`root_height.root_offsets`);
3. a leg pose solve where a foot is still below the floor (the longer leg of an asymmetric
   body, or a swing foot of a long-legged one): damped least squares on that leg's joints
   with the MuJoCo Jacobian lifts the foot by its penetration, keeping its orientation and
   horizontal position (the paper's contact-point objective, solved per frame); under
   "foot_tracks" a longer leg is shortened on every frame by its track's depth, swing too,
   so the bend is continuous (`root_height.foot_goals`). A knee the
   clip bends one way only stays on that side in the solve (`leg_solve.bend_side_bounds`), so the
   solution does not flip between frames.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import mujoco
import numpy as np

from common.motion.clip import Clip
from common.motion.leg_solve import Leg, lift_foot
from common.motion.qpos_map import QposMap
from common.motion.reference import CharacterMotion
from common.motion.retarget_config import RetargetConfig
from common.motion.root_height import (ROOT_HEIGHT_RULES, foot_geom_ids, foot_goals, foot_heights, frame_distances,
                                       lowest_points, lowest_z, root_offsets)


@dataclass(frozen=True)
class ContactPhases:
    """Per-frame foot contacts of a clip on its base character: flags (T, F) bool in
    `foot_geoms` order; ground_m the clip's own floor height on the base character."""

    foot_geoms: tuple[str, ...]
    flags: np.ndarray
    ground_m: float


def contact_phases(clip: Clip, base_model: mujoco.MjModel, foot_geoms: tuple[str, ...], cfg: RetargetConfig = RetargetConfig()) -> ContactPhases:
    """Which foot touches the floor in which frame, from the clip on its base character.

    The clip's floor is the 10th percentile of the lower foot's height (robust to a few
    sunken frames); contact = near that floor and slow (see RetargetConfig).
    """
    qpos = QposMap(clip, base_model).to_qpos(clip.root_pos, clip.root_quat, clip.joint_qpos)
    return frame_contact_phases(qpos, clip.fps, base_model, foot_geoms, cfg)


def frame_contact_phases(qpos: np.ndarray, fps: float, base_model: mujoco.MjModel, foot_geoms: tuple[str, ...],
                         cfg: RetargetConfig = RetargetConfig()) -> ContactPhases:
    """`contact_phases` of qpos frames `[T, nq]` of the base character at `fps` (a clip already
    played on it, e.g. one cleaned by `common.motion.clean`)."""
    h, pos = foot_heights(base_model, qpos, foot_geoms)
    ground = float(np.percentile(h.min(axis=1), 10))
    speed = np.linalg.norm(np.gradient(pos[:, :, :2], axis=0), axis=-1) * fps
    flags = (h - ground < cfg.contact_height_m) & (speed < cfg.contact_speed_m_s)
    return ContactPhases(tuple(foot_geoms), flags, ground)


def retarget_qpos(clip: Clip, model: mujoco.MjModel, foot_geoms: tuple[str, ...], leg_ratio: float,
                  contacts: ContactPhases, cfg: RetargetConfig = RetargetConfig()) -> np.ndarray:
    """qpos frames (T, nq) of `clip` on a shaped `model` with feet on the floor (module docstring)."""
    qpos = QposMap(clip, model).to_qpos(clip.root_pos, clip.root_quat, clip.joint_qpos)
    return retarget_frames(qpos, clip.fps, clip.loop, model, foot_geoms, leg_ratio, contacts, cfg)


def retarget_frames(qpos: np.ndarray, fps: float, loop: bool, model: mujoco.MjModel, foot_geoms: tuple[str, ...],
                    leg_ratio: float, contacts: ContactPhases, cfg: RetargetConfig = RetargetConfig()) -> np.ndarray:
    """`retarget_qpos` of qpos frames `[T, nq]` (at `fps`; `loop`: the clip loops) that already
    carry the clip's joint angles in `model`'s layout (a clip played on the base character: a
    shape moves no joint's rest orientation, so its joint angles are the same qpos on every
    shape); changed in place and returned. `contacts` are those of the same frames on the base."""
    xy0 = qpos[0, :2].copy()
    qpos[:, :2] = xy0 + leg_ratio * (qpos[:, :2] - xy0)
    qpos[:, 2] = leg_ratio * (qpos[:, 2] - contacts.ground_m)
    h, _ = foot_heights(model, qpos, foot_geoms)
    dz = root_offsets(h, contacts.flags, cfg.root_height, loop, max_step=cfg.root_speed_m_s / fps)
    qpos[:, 2] += dz
    h = h + dz[:, None]
    data = mujoco.MjData(model)
    legs = [Leg.of(model, int(model.geom(f).bodyid[0]), qpos) for f in foot_geoms]
    geoms = [foot_geom_ids(model, f) for f in foot_geoms]
    goal = foot_goals(h, contacts.flags, cfg.root_height, loop)
    for k, i in zip(*np.nonzero(goal - h > cfg.ik_tolerance_m)):
        data.qpos[:] = qpos[k]
        depth = goal[k, i] - h[k, i]
        legs[i].unstraighten(data)
        # NOTE: the foot may tilt a little while it rises, so its lowest point can lag its
        # body: measure again and lift the rest, a few rounds at most.
        for attempt in range(4):
            before = depth
            lift_foot(model, data, legs[i], depth, cfg)
            depth = goal[k, i] - lowest_z(model, data, geoms[i])
            if depth < cfg.ik_tolerance_m:
                break
            if depth > before - 1e-3:
                # NOTE: a straight leg is a singular pose (no first-order way to shorten it):
                # bend the chain a little, one way then the other, and solve again.
                kick = np.zeros(model.nv)
                side = legs[i].side_by_dof  # a narrowed knee is bent its own way
                kick[legs[i].dofs] = np.where(side != 0.0, 0.2 * side, 0.1 if attempt % 2 == 0 else -0.2)
                mujoco.mj_integratePos(model, data.qpos, kick, 1.0)
                legs[i].clamp_hinges(data)
                mujoco.mj_kinematics(model, data)
                depth = goal[k, i] - lowest_z(model, data, geoms[i])
        qpos[k] = data.qpos
    if cfg.body_clearance_m > 0:
        qpos[:, 2] += clearance_lift(model, qpos, foot_geoms, cfg.body_clearance_m, cfg.ramp_s * fps, loop,
                                     cfg.clearance_shins_may_touch)
    return qpos


def clearance_lift(model: mujoco.MjModel, qpos: np.ndarray, foot_geoms: tuple[str, ...], clearance_m: float,
                   ramp_frames: float, loop: bool = False, shins_may_touch: bool = False) -> np.ndarray:
    """Per-frame root lift `[T]` (m) that keeps every geom of the bodies whose floor contact is
    a fall at least `clearance_m` above the floor: every body but the feet and what hangs below
    them, and with `shins_may_touch` also but the segment above each foot (the task's rule,
    `ImitateConfig.shin_contact_is_fall`). Each frame's deficit is spread as a tent over
    `ramp_frames` frames on each side (the largest tent wins), so the root rises and settles
    continuously. Under Won & Lee's fall rule (any floor contact but a foot's) a reference
    whose shin reaches the floor asks for a fall; a shank box that is deep for its shape dips to
    the floor at heel strike and toe-off (docs/experiments/2026-12-04-lower-biped-shank.md)."""
    n = len(qpos)
    roots = {int(model.geom(f).bodyid[0]) for f in foot_geoms}
    if shins_may_touch:
        roots |= {int(model.body_parentid[b]) for b in roots}

    def exempt(b: int) -> bool:
        while b > 0:
            if b in roots:
                return True
            b = int(model.body_parentid[b])
        return False

    geoms = np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] > 0 and not exempt(int(model.geom_bodyid[g]))],
                     dtype=np.int64)
    if len(geoms) == 0:
        return np.zeros(n)
    data = mujoco.MjData(model)
    deficit = np.zeros(n)
    for k in range(n):
        data.qpos[:] = qpos[k]
        mujoco.mj_kinematics(model, data)
        low = lowest_points(model, geoms, data.geom_xpos[geoms][None], data.geom_xmat[geoms][None])[0].min()
        deficit[k] = max(0.0, clearance_m - float(low))
    if not deficit.any():
        return deficit
    lift = np.zeros(n)
    for j in np.flatnonzero(deficit):
        lift = np.maximum(lift, deficit[j] * np.clip(1.0 - frame_distances(n, int(j), loop) / max(ramp_frames, 1e-9), 0.0, 1.0))
    return lift


def character_feet(character) -> tuple[str, ...]:
    """Foot geom names of a `common.characters.Character` (empty for swimmers)."""
    return tuple(getattr(character, "foot_geoms", ()) or ())


def swim_path_scaled(clip: Clip, ratio: float) -> Clip:
    """A swimmer's clip with its root path scaled by `ratio` (body length over the base's) about
    the first frame: a body twice as long covers twice the distance per stroke cycle. This is
    the swimmer's counterpart of the walkers' stride scaling, and what the task's target
    velocity (v0 times the same length ratio, reward normalization) assumes. (The stroke of a
    random shape may still be slower or faster than that: `common.tasks.shape.stroke_speed`.)"""
    if not np.isfinite(ratio) or ratio <= 0:
        raise ValueError(f"length ratio {ratio!r} must be a finite number > 0")
    return dataclasses.replace(clip, root_pos=clip.root_pos[0] + ratio * (clip.root_pos - clip.root_pos[0]))


def leg_length_ratio(character, base_character) -> float:
    """r = mean leg length of `character` / that of `base_character` (`Character.leg_lengths_m`):
    what root height and stride are scaled by (module docstring, 1)."""
    return float(np.mean(character.leg_lengths_m) / np.mean(base_character.leg_lengths_m))


def play_on(clip: Clip, character, base_character=None, cfg: RetargetConfig = RetargetConfig(),
            contacts: ContactPhases | None = None) -> CharacterMotion:
    """The clip retargeted onto `character` (a shaped `common.characters.Character`).

    base_character: the same preset at its default shape (built when not given); contacts:
    precomputed `contact_phases` to reuse across many shapes.
    """
    feet = character_feet(character)
    ees = tuple(getattr(character, "end_effector_bodies", ()))
    if base_character is None:
        # lazy: start-up time of train --help, which loads common.motion (common.characters adds scipy.optimize)
        from common.characters import load_character

        base_character = load_character(character.preset)
    if not feet:
        return CharacterMotion.from_clip(swim_path_scaled(clip, character.length_m / base_character.length_m),
                                         character.model, ees)
    if contacts is None:
        contacts = contact_phases(clip, base_character.model, feet, cfg)
    qpos = retarget_qpos(clip, character.model, feet, leg_length_ratio(character, base_character), contacts, cfg)
    return CharacterMotion(clip, character.model, qpos, ees)
