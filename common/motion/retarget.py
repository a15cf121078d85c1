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
   its own swing instead, so the offset is continuous (`root_offsets`);
3. a leg pose solve where a foot is still below the floor (the longer leg of an asymmetric
   body, or a swing foot of a long-legged one): damped least squares on that leg's joints
   with the MuJoCo Jacobian lifts the foot by its penetration, keeping its orientation and
   horizontal position (the paper's contact-point objective, solved per frame); under
   "foot_tracks" a longer leg is shortened on every frame by its track's depth, swing too,
   so the bend is continuous (`foot_goals`). A knee the
   clip bends one way only stays on that side in the solve (`bend_side_bounds`), so the
   solution does not flip between frames.
"""

from __future__ import annotations

import dataclasses

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
    root_height: str = "contact_set"
    """How the per-frame root offset is chosen (`root_offsets`): "contact_set" puts the highest
    foot of each frame's contact set on the floor; "foot_tracks" the highest of every foot's
    in-contact height, interpolated through that foot's swing (continuous across contact-set
    changes: no root drop when a shorter leg's pair takes over), and the leg solve then shortens
    each longer leg by its track's depth below the floor on every frame (`foot_goals`)."""

    def __post_init__(self) -> None:
        if self.root_height not in ROOT_HEIGHT_RULES:
            raise ValueError(f"root_height {self.root_height!r} is not one of {' | '.join(ROOT_HEIGHT_RULES)}")


ROOT_HEIGHT_RULES = ("contact_set", "foot_tracks")


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


def _lowest_points(model: mujoco.MjModel, geom_ids: np.ndarray, xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
    """Height (m) of the lowest point of geoms `geom_ids` [G] in poses given by their world
    positions `xpos` [T, G, 3] and rotation matrices `xmat` [T, G, 9]: [T, G] (exact for
    primitive shapes, the bounding sphere for others)."""
    r = xmat.reshape(*xmat.shape[:-1], 3, 3)[..., 2, :]  # world z row of each geom's rotation
    drop = np.empty(r.shape[:-1])
    for kind in set(model.geom_type[geom_ids].tolist()):
        sel = model.geom_type[geom_ids] == kind
        size, rk = model.geom_size[geom_ids[sel]], r[..., sel, :]
        if kind == mujoco.mjtGeom.mjGEOM_BOX:
            drop[..., sel] = np.sum(np.abs(rk) * size, axis=-1)
        elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            drop[..., sel] = size[:, 0]
        elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
            drop[..., sel] = np.abs(rk[..., 2]) * size[:, 1] + size[:, 0]
        elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
            drop[..., sel] = np.abs(rk[..., 2]) * size[:, 1] + size[:, 0] * np.sqrt(np.maximum(0.0, 1.0 - rk[..., 2] ** 2))
        elif kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
            drop[..., sel] = np.sqrt(np.sum((rk * size) ** 2, axis=-1))
        else:
            drop[..., sel] = model.geom_rbound[geom_ids[sel]]
    return xpos[..., 2] - drop


def lowest_z(model: mujoco.MjModel, data: mujoco.MjData, geom_ids: np.ndarray) -> float:
    """Height (m) of the lowest point of some geoms in the current pose (exact for primitive shapes)."""
    return float(_lowest_points(model, geom_ids, data.geom_xpos[geom_ids], data.geom_xmat[geom_ids]).min())


def foot_heights(model: mujoco.MjModel, qpos_frames: np.ndarray, foot_geoms: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(heights (T, F) m of each foot's lowest point, foot body positions (T, F, 3) m)."""
    data = mujoco.MjData(model)
    geoms = [_geoms_of(model, f) for f in foot_geoms]
    every = np.concatenate(geoms)
    bodies = [int(model.geom(f).bodyid[0]) for f in foot_geoms]
    xpos = np.zeros((len(qpos_frames), len(every), 3))
    xmat = np.zeros((len(qpos_frames), len(every), 9))
    pos = np.zeros((len(qpos_frames), len(foot_geoms), 3))
    for k, q in enumerate(qpos_frames):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        xpos[k] = data.geom_xpos[every]
        xmat[k] = data.geom_xmat[every]
        pos[k] = data.xpos[bodies]
    low = _lowest_points(model, every, xpos, xmat)
    ends = np.cumsum([len(g) for g in geoms])
    h = np.stack([low[:, e - len(g):e].min(axis=1) for g, e in zip(geoms, ends)], axis=1)
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


@dataclass(frozen=True)
class _Leg:
    """What the leg solve needs of one foot, computed once per retarget: the foot body, the DOFs
    between root and foot, and the limited hinges among them (qpos address, lower, upper; a
    hinge that may turn both ways but that the clip bends one way only is narrowed to that
    side, `bend_side_bounds`, and `hinge_side` says which: +1, -1, or 0 if not narrowed)."""

    body: int
    dofs: np.ndarray
    hinge_qpos: np.ndarray
    hinge_lo: np.ndarray
    hinge_hi: np.ndarray
    hinge_side: np.ndarray
    side_by_dof: np.ndarray
    """`hinge_side` per entry of `dofs` (0 for the other DOFs)."""

    @staticmethod
    def of(model: mujoco.MjModel, body: int, qpos_frames: np.ndarray | None = None) -> "_Leg":
        dofs = _leg_dofs(model, body)
        joints = sorted(set(model.dof_jntid[dofs].tolist()))
        hinges = [j for j in joints if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE and model.jnt_limited[j]]
        adr = model.jnt_qposadr[hinges].astype(np.int64)
        lo, hi = model.jnt_range[hinges, 0].copy(), model.jnt_range[hinges, 1].copy()
        side = np.zeros(len(hinges))
        if qpos_frames is not None:
            new_lo, new_hi = bend_side_bounds(qpos_frames[:, adr], lo, hi)
            side = np.where(new_lo > lo, 1.0, np.where(new_hi < hi, -1.0, 0.0))
            lo, hi = new_lo, new_hi
        by_dof = np.zeros(len(dofs))
        for j, sd in zip(hinges, side):
            by_dof[dofs == model.jnt_dofadr[j]] = sd
        return _Leg(body, dofs, adr, lo, hi, side, by_dof)

    def clamp_hinges(self, data: mujoco.MjData) -> None:
        """Keep limited hinge joints (knees) inside their range and on the clip's bend side: a
        solve must not bend a knee backward."""
        data.qpos[self.hinge_qpos] = np.clip(data.qpos[self.hinge_qpos], self.hinge_lo, self.hinge_hi)

    def unstraighten(self, data: mujoco.MjData, angle: float = 0.05) -> None:
        """Bend each narrowed hinge that is within `angle` (rad) of straight to `angle` on its
        side: a straight leg is singular, and the solve's steps would push the knee against its
        new 0 bound and stall there (a foot left 13 cm below the floor, measured)."""
        q = data.qpos[self.hinge_qpos]
        data.qpos[self.hinge_qpos] = np.where((self.hinge_side != 0.0) & (np.abs(q) < angle), self.hinge_side * angle, q)


BEND_EPS_RAD = 1e-3
"""A hinge whose clip angle never goes past 0 by more than this, on one side, bends only the
other way (`bend_side_bounds`)."""


def bend_side_bounds(angles: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joint bounds `(lo, hi)` of limited hinges narrowed to the side of 0 their clip angles
    `angles [T, H]` keep to: a knee the clip bends only one way (a quadruped's front knees
    negative, its hind knees positive) gets [lo, 0] or [0, hi]; a hinge the clip moves through
    0 (or never moves) keeps its range.

    Why: the quadruped's knees may turn either way (range +-2.4 rad). A straight leg is a
    singular pose, and the leg solve that lifts a too-long leg's foot (Won & Lee 2019, METHOD.md
    A: the per-frame pose solve after F) would bend the knee whichever way its first step
    happened to go, frame by frame: measured on 150 random quadruped shapes, every one had a
    knee that flipped by 1.9-3.6 rad between two frames of its reference, a PD target no body
    can follow. A hinge whose range is already one-sided (a biped's knee, [0, 2.3]) is
    unchanged."""
    angles = np.asarray(angles, dtype=np.float64)
    lo, hi = np.array(lo, dtype=np.float64), np.array(hi, dtype=np.float64)
    if angles.size == 0:
        return lo, hi
    bends_neg = (angles.max(axis=0) <= BEND_EPS_RAD) & (angles.min(axis=0) < -BEND_EPS_RAD)
    bends_pos = (angles.min(axis=0) >= -BEND_EPS_RAD) & (angles.max(axis=0) > BEND_EPS_RAD)
    hi = np.where(bends_neg, np.minimum(hi, 0.0), hi)
    lo = np.where(bends_pos, np.maximum(lo, 0.0), lo)
    return lo, hi


def _lift_foot(model: mujoco.MjModel, data: mujoco.MjData, leg: _Leg, lift_m: float, cfg: RetargetConfig) -> None:
    """Raise a foot body by lift_m (m) keeping its orientation, moving only the leg's DOFs; in
    place on data.qpos. Damped Gauss-Newton; the normal equations (n_dofs square) are solved
    with MuJoCo's Cholesky, which costs a tenth of numpy's per-call overhead at this size."""
    body, dofs, n = leg.body, leg.dofs, len(leg.dofs)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    target_p = data.xpos[body] + np.array([0.0, 0.0, lift_m])
    target_q = data.xquat[body].copy()
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    err, err_r, qv = np.zeros(6), np.zeros(3), np.zeros(model.nv)
    w = cfg.ik_orientation_weight_m
    damping = cfg.ik_damping * np.eye(n)
    jac = np.zeros((6, n))
    step = np.zeros(n)
    for _ in range(cfg.ik_iterations):
        err[:3] = target_p - data.xpos[body]
        if err[0] * err[0] + err[1] * err[1] + err[2] * err[2] < 1e-8:
            break
        mujoco.mj_jacBody(model, data, jacp, jacr, body)
        mujoco.mju_subQuat(err_r, target_q, data.xquat[body])
        err[3:] = w * err_r
        jac[:3] = jacp[:, dofs]
        jac[3:] = w * jacr[:, dofs]
        normal = jac.T @ jac + damping
        mujoco.mju_cholFactor(normal, 0.0)
        mujoco.mju_cholSolve(step, normal, jac.T @ err)
        qv[dofs] = step
        mujoco.mj_integratePos(model, data.qpos, qv, 1.0)
        leg.clamp_hinges(data)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)


def root_offsets(h: np.ndarray, flags: np.ndarray, rule: str = "contact_set", loop: bool = False) -> np.ndarray:
    """Per-frame vertical root offsets `[T]` (m) that put the feet on the floor, from each foot's
    lowest-point height `h [T, F]` (m, before the offset) and its contact flags `[T, F]` on the
    base character (Won & Lee 2019, METHOD.md A: after F, the feet touch the ground; this is the
    per-frame version of that pose solve's vertical root DOF, the legs' solve follows).

    "contact_set": minus the highest foot in contact at each frame, interpolated in time across
    frames without contact. "foot_tracks": each foot's height on its contact frames,
    interpolated in time across its swing, gives a track per foot; the offset is minus the
    highest track. Both put every contact foot at or below the floor (the leg solve lifts the
    rest); only "foot_tracks" is continuous when the contact set changes. `loop`: the clip's
    last frame is its first again (`Clip.loop`), so a gap at the ends is bridged around the
    loop (period T - 1 frames); otherwise the first and last contact values are held.
    No contact anywhere: minus the 10th percentile of the lowest foot (the clip's floor)."""
    in_contact = flags.any(axis=1)
    if not in_contact.any():
        return np.full(len(h), -float(np.percentile(h.min(axis=1), 10)))
    if rule == "contact_set":
        highest = np.where(flags, h, -np.inf).max(axis=1)
        return -_bridge(in_contact, np.where(in_contact, highest, 0.0), loop)
    if rule == "foot_tracks":
        return -np.max(foot_tracks(h, flags, loop), axis=1)
    raise ValueError(f"root height rule {rule!r} is not one of {' | '.join(ROOT_HEIGHT_RULES)}")


def foot_tracks(h: np.ndarray, flags: np.ndarray, loop: bool = False) -> np.ndarray:
    """Each foot's planted height `[T, F]` (m): `h` on its contact frames, interpolated in time
    across its swing (around the loop for a looping clip, else held at the ends); -inf for a foot
    never in contact. Needs at least one contact somewhere."""
    out = np.full(h.shape, -np.inf)
    for i in range(h.shape[1]):
        if flags[:, i].any():
            out[:, i] = _bridge(flags[:, i], h[:, i], loop)
    return out


def _bridge(where: np.ndarray, values: np.ndarray, loop: bool) -> np.ndarray:
    """`values [T]` kept where `where` (not all False), linearly interpolated in time between:
    around the loop (period T - 1 frames: a loop's last frame repeats the first) or held at the
    ends for a clip played once."""
    frames = np.arange(len(values))
    period = len(values) - 1 if loop and len(values) > 2 else None
    keep = where & (frames < period) if period else where
    if not keep.any():  # only the repeated last frame: it is frame 0's
        keep = where
    return np.interp(frames, frames[keep], values[keep], period=period)


def foot_goals(h: np.ndarray, flags: np.ndarray, rule: str = "contact_set", loop: bool = False) -> np.ndarray:
    """Where each foot's lowest point should be `[T, F]` (m above the floor), given its height
    `h` after the root offset (`root_offsets`): on or above the floor always; with
    "foot_tracks" also as high above the floor as it is above its own track in the clip, so a
    longer leg is shortened by its track's depth below the floor on every frame, swing too. The
    shortening is then continuous in time (lifting a foot only while it is below the floor
    bends a long leg at touchdown within one frame: the knee went from the clip's 0 to 1.1
    rad between two frames on a random quadruped)."""
    goal = np.maximum(h, 0.0)
    if rule == "foot_tracks" and flags.any():
        tracks = foot_tracks(h, flags, loop)
        has = np.isfinite(tracks)
        clearance = np.where(has, h - tracks, h)
        goal = np.where(has, np.maximum(clearance, 0.0), goal)
    return goal


def retarget_qpos(clip: Clip, model: mujoco.MjModel, foot_geoms: tuple[str, ...], leg_ratio: float,
                  contacts: ContactPhases, cfg: RetargetConfig = RetargetConfig()) -> np.ndarray:
    """qpos frames (T, nq) of `clip` on a shaped `model` with feet on the floor (module docstring)."""
    qpos = QposMap(clip, model).to_qpos(clip.root_pos, clip.root_quat, clip.joint_qpos)
    xy0 = qpos[0, :2].copy()
    qpos[:, :2] = xy0 + leg_ratio * (qpos[:, :2] - xy0)
    qpos[:, 2] = leg_ratio * (qpos[:, 2] - contacts.ground_m)
    h, _ = foot_heights(model, qpos, foot_geoms)
    dz = root_offsets(h, contacts.flags, cfg.root_height, clip.loop)
    qpos[:, 2] += dz
    h = h + dz[:, None]
    data = mujoco.MjData(model)
    legs = [_Leg.of(model, int(model.geom(f).bodyid[0]), qpos) for f in foot_geoms]
    geoms = [_geoms_of(model, f) for f in foot_geoms]
    goal = foot_goals(h, contacts.flags, cfg.root_height, clip.loop)
    for k, i in zip(*np.nonzero(goal - h > cfg.ik_tolerance_m)):
        data.qpos[:] = qpos[k]
        depth = goal[k, i] - h[k, i]
        legs[i].unstraighten(data)
        # NOTE: the foot may tilt a little while it rises, so its lowest point can lag its
        # body: measure again and lift the rest, a few rounds at most.
        for attempt in range(4):
            before = depth
            _lift_foot(model, data, legs[i], depth, cfg)
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
    return qpos


def character_feet(character) -> tuple[str, ...]:
    """Foot geom names of a `common.characters.Character` (empty for swimmers)."""
    return tuple(getattr(character, "foot_geoms", ()) or ())


def swim_path_scaled(clip: Clip, ratio: float) -> Clip:
    """A swimmer's clip with its root path scaled by `ratio` (body length over the base's) about
    the first frame: a body twice as long covers twice the distance per stroke cycle. This is
    the swimmer's counterpart of the walkers' stride scaling, and what the task's target
    velocity (v0 times the same length ratio, reward normalization) and its fall rule (the root
    within so many body lengths of the reference root) assume."""
    if not np.isfinite(ratio) or ratio <= 0:
        raise ValueError(f"length ratio {ratio!r} must be a finite number > 0")
    return dataclasses.replace(clip, root_pos=clip.root_pos[0] + ratio * (clip.root_pos - clip.root_pos[0]))


def play_on(clip: Clip, character, base_character=None, cfg: RetargetConfig = RetargetConfig(),
            contacts: ContactPhases | None = None) -> CharacterMotion:
    """The clip retargeted onto `character` (a shaped `common.characters.Character`).

    base_character: the same preset at its default shape (built when not given); contacts:
    precomputed `contact_phases` to reuse across many shapes.
    """
    feet = character_feet(character)
    ees = tuple(getattr(character, "end_effector_bodies", ()))
    if base_character is None:
        from common.characters import load_character

        base_character = load_character(character.preset)
    if not feet:
        return CharacterMotion.from_clip(swim_path_scaled(clip, character.length_m / base_character.length_m),
                                         character.model, ees)
    if contacts is None:
        contacts = contact_phases(clip, base_character.model, feet, cfg)
    ratio = float(np.mean(character.leg_lengths_m) / np.mean(base_character.leg_lengths_m))
    qpos = retarget_qpos(clip, character.model, feet, ratio, contacts, cfg)
    return CharacterMotion(clip, character.model, qpos, ees)
