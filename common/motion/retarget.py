"""Play a clip on a character of any shape with the feet on the floor.

Won & Lee 2019 (METHOD.md A) retarget the reference to each body shape: a shape changes limb
lengths, so the clip's root height and root speed no longer fit the legs, and feet would
sink into or float above the ground. Joint rotations carry over unchanged (the same motion,
another body); what changes is:
1. root velocity and height scaled by the leg-length ratio r = mean leg / base mean leg
   (the horizontal path is scaled about the first frame, so strides fit the legs);
2. a per-frame vertical root offset that puts the *highest* foot in contact on the floor
   (contact phases come from the clip on the base character); between contact phases the
   offset is interpolated in time, which keeps jumps and flips' flight arcs;
3. a leg pose solve where a foot is still below the floor (the longer leg of an asymmetric
   body, or a swing foot of a long-legged one): damped least squares on that leg's joints
   with the MuJoCo Jacobian lifts the foot by its penetration, keeping its orientation and
   horizontal position (the paper's contact-point objective, solved per frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from common.motion.clip import Clip
from common.motion.qpos_map import QposMap
from common.motion.reference import CharacterMotion


@dataclass(frozen=True)
class RetargetConfig:
    """Thresholds of the retargeting (metres, m/s)."""

    contact_height_m: float = 0.04
    """A foot is in contact on the base character when its lowest point is this close to the clip's floor..."""
    contact_speed_m_s: float = 0.8
    """...and its body moves horizontally slower than this."""
    ik_tolerance_m: float = 0.005
    """Penetrations deeper than this are removed by the leg pose solve."""
    ik_iterations: int = 25
    """Gauss-Newton steps per frame and foot (at most; stops when the foot is there)."""
    ik_orientation_weight_m: float = 0.2
    """Weight (m/rad) of keeping the foot's orientation against reaching its height."""
    ik_damping: float = 1e-3
    """Levenberg damping of the leg solve (m^2)."""


@dataclass(frozen=True)
class ContactPhases:
    """Per-frame foot contacts of a clip on its base character: flags (T, F) bool in
    `foot_geoms` order; ground_m the clip's own floor height on the base character."""

    foot_geoms: tuple[str, ...]
    flags: np.ndarray
    ground_m: float


def _geoms_of(model: mujoco.MjModel, foot_geom: str) -> np.ndarray:
    """Geom ids of the foot geom's body and of all bodies below it (toes)."""
    body = model.geom(foot_geom).bodyid[0]
    bodies = {int(body)}
    for b in range(model.nbody):
        p = b
        while p > 0:
            if p == body:
                bodies.add(b)
                break
            p = model.body_parentid[p]
    return np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies], dtype=np.int64)


def lowest_z(model: mujoco.MjModel, data: mujoco.MjData, geom_ids: np.ndarray) -> float:
    """Height (m) of the lowest point of some geoms in the current pose (exact for primitive shapes)."""
    out = np.inf
    for g in geom_ids:
        r = data.geom_xmat[g].reshape(3, 3)[2]
        s = model.geom_size[g]
        z = data.geom_xpos[g, 2]
        kind = model.geom_type[g]
        if kind == mujoco.mjtGeom.mjGEOM_BOX:
            z -= np.abs(r) @ s
        elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            z -= s[0]
        elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
            z -= abs(r[2]) * s[1] + s[0]
        elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
            z -= abs(r[2]) * s[1] + s[0] * np.sqrt(max(0.0, 1.0 - r[2] ** 2))
        elif kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
            z -= np.sqrt(np.sum((r * s) ** 2))
        else:
            z -= model.geom_rbound[g]
        out = min(out, z)
    return float(out)


def foot_heights(model: mujoco.MjModel, qpos_frames: np.ndarray, foot_geoms: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(heights (T, F) m of each foot's lowest point, foot body positions (T, F, 3) m)."""
    data = mujoco.MjData(model)
    geoms = [_geoms_of(model, f) for f in foot_geoms]
    bodies = [int(model.geom(f).bodyid[0]) for f in foot_geoms]
    h = np.zeros((len(qpos_frames), len(foot_geoms)))
    pos = np.zeros((len(qpos_frames), len(foot_geoms), 3))
    for k, q in enumerate(qpos_frames):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        for i, g in enumerate(geoms):
            h[k, i] = lowest_z(model, data, g)
            pos[k, i] = data.xpos[bodies[i]]
    return h, pos


def contact_phases(clip: Clip, base_model: mujoco.MjModel, foot_geoms: tuple[str, ...], cfg: RetargetConfig = RetargetConfig()) -> ContactPhases:
    """Which foot touches the floor in which frame, from the clip on its base character.

    The clip's floor is the 10th percentile of the lower foot's height (robust to a few
    sunken frames); contact = near that floor and slow (see RetargetConfig).
    """
    qpos = QposMap(clip, base_model).to_qpos(clip.root_pos, clip.root_quat, clip.joint_qpos)
    h, pos = foot_heights(base_model, qpos, foot_geoms)
    ground = float(np.percentile(h.min(axis=1), 10))
    speed = np.linalg.norm(np.gradient(pos[:, :, :2], axis=0), axis=-1) * clip.fps
    flags = (h - ground < cfg.contact_height_m) & (speed < cfg.contact_speed_m_s)
    return ContactPhases(tuple(foot_geoms), flags, ground)


def _leg_dofs(model: mujoco.MjModel, body: int) -> np.ndarray:
    """DOF indices of the joints between the root body and `body` (inclusive of `body`)."""
    dofs = []
    root = int(model.jnt_bodyid[0])
    b = body
    while b > 0 and b != root:
        for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b]):
            n = {mujoco.mjtJoint.mjJNT_BALL: 3, mujoco.mjtJoint.mjJNT_HINGE: 1, mujoco.mjtJoint.mjJNT_SLIDE: 1}[int(model.jnt_type[j])]
            dofs.extend(range(model.jnt_dofadr[j], model.jnt_dofadr[j] + n))
        b = int(model.body_parentid[b])
    return np.array(sorted(dofs), dtype=np.int64)


def _clamp_hinges(model: mujoco.MjModel, data: mujoco.MjData, joints: list[int]) -> None:
    """Keep limited hinge joints (knees) inside their range: a solve must not bend a knee backward."""
    for j in joints:
        adr = model.jnt_qposadr[j]
        data.qpos[adr] = np.clip(data.qpos[adr], *model.jnt_range[j])


def _lift_foot(model: mujoco.MjModel, data: mujoco.MjData, body: int, dofs: np.ndarray, lift_m: float, cfg: RetargetConfig) -> None:
    """Raise a foot body by lift_m (m) keeping its orientation, moving only `dofs`; in place on data.qpos."""
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    target_p = data.xpos[body] + np.array([0.0, 0.0, lift_m])
    target_q = data.xquat[body].copy()
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    err_r, qv = np.zeros(3), np.zeros(model.nv)
    hinges = [j for j in sorted(set(model.dof_jntid[dofs].tolist()))
              if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE and model.jnt_limited[j]]
    for _ in range(cfg.ik_iterations):
        mujoco.mj_jacBody(model, data, jacp, jacr, body)
        mujoco.mju_subQuat(err_r, target_q, data.xquat[body])
        w = cfg.ik_orientation_weight_m
        err = np.concatenate([target_p - data.xpos[body], w * err_r])
        if np.linalg.norm(err[:3]) < 1e-4:
            break
        jac = np.concatenate([jacp[:, dofs], w * jacr[:, dofs]])
        step = np.linalg.solve(jac.T @ jac + cfg.ik_damping * np.eye(len(dofs)), jac.T @ err)
        qv[:] = 0.0
        qv[dofs] = step
        mujoco.mj_integratePos(model, data.qpos, qv, 1.0)
        _clamp_hinges(model, data, hinges)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)


def retarget_qpos(clip: Clip, model: mujoco.MjModel, foot_geoms: tuple[str, ...], leg_ratio: float,
                  contacts: ContactPhases, cfg: RetargetConfig = RetargetConfig()) -> np.ndarray:
    """qpos frames (T, nq) of `clip` on a shaped `model` with feet on the floor (module docstring)."""
    qpos = QposMap(clip, model).to_qpos(clip.root_pos, clip.root_quat, clip.joint_qpos)
    xy0 = qpos[0, :2].copy()
    qpos[:, :2] = xy0 + leg_ratio * (qpos[:, :2] - xy0)
    qpos[:, 2] = leg_ratio * (qpos[:, 2] - contacts.ground_m)
    h, _ = foot_heights(model, qpos, foot_geoms)
    flags = contacts.flags
    in_contact = flags.any(axis=1)
    if in_contact.any():
        highest = np.where(flags, h, -np.inf).max(axis=1)
        frames = np.flatnonzero(in_contact)
        dz = np.interp(np.arange(len(qpos)), frames, -highest[frames])
    else:
        dz = np.full(len(qpos), -float(np.percentile(h.min(axis=1), 10)))
    qpos[:, 2] += dz
    h = h + dz[:, None]
    data = mujoco.MjData(model)
    bodies = [int(model.geom(f).bodyid[0]) for f in foot_geoms]
    dofs = [_leg_dofs(model, b) for b in bodies]
    geoms = [_geoms_of(model, f) for f in foot_geoms]
    for k, i in zip(*np.nonzero(h < -cfg.ik_tolerance_m)):
        data.qpos[:] = qpos[k]
        depth = -h[k, i]
        # NOTE: the foot may tilt a little while it rises, so its lowest point can lag its
        # body: measure again and lift the rest, a few rounds at most.
        for attempt in range(4):
            before = depth
            _lift_foot(model, data, bodies[i], dofs[i], depth, cfg)
            depth = -lowest_z(model, data, geoms[i])
            if depth < cfg.ik_tolerance_m:
                break
            if depth > before - 1e-3:
                # NOTE: a straight leg is a singular pose (no first-order way to shorten it):
                # bend the chain a little, one way then the other, and solve again.
                kick = np.zeros(model.nv)
                kick[dofs[i]] = 0.1 if attempt % 2 == 0 else -0.2
                mujoco.mj_integratePos(model, data.qpos, kick, 1.0)
                _clamp_hinges(model, data, [j for j in set(model.dof_jntid[dofs[i]].tolist())
                                            if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE and model.jnt_limited[j]])
                mujoco.mj_kinematics(model, data)
                depth = -lowest_z(model, data, geoms[i])
        qpos[k] = data.qpos
    return qpos


def character_feet(character) -> tuple[str, ...]:
    """Foot geom names of a `common.characters.Character` (empty for swimmers)."""
    return tuple(getattr(character, "foot_geoms", ()) or ())


def play_on(clip: Clip, character, base_character=None, cfg: RetargetConfig = RetargetConfig(),
            contacts: ContactPhases | None = None) -> CharacterMotion:
    """The clip retargeted onto `character` (a shaped `common.characters.Character`).

    base_character: the same preset at its default shape (built when not given); contacts:
    precomputed `contact_phases` to reuse across many shapes.
    """
    feet = character_feet(character)
    ees = tuple(getattr(character, "end_effector_bodies", ()))
    if not feet:
        return CharacterMotion.from_clip(clip, character.model, ees)
    if base_character is None:
        from common.characters import load_character

        base_character = load_character(character.preset)
    if contacts is None:
        contacts = contact_phases(clip, base_character.model, feet, cfg)
    ratio = float(np.mean(character.leg_lengths_m) / np.mean(base_character.leg_lengths_m))
    qpos = retarget_qpos(clip, character.model, feet, ratio, contacts, cfg)
    return CharacterMotion(clip, character.model, qpos, ees)
