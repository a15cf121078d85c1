"""Where the feet are and how high the root must sit so they touch the floor.

The first half measures: the lowest point of a foot's geoms in any pose (exact for primitive
shapes), per frame of a clip. The second half is the root-height rule of the retargeting
(`retarget.py`, Won & Lee 2019, METHOD.md A): from each foot's height and its contact flags, a
per-frame vertical root offset ("contact_set" or "foot_tracks", `ROOT_HEIGHT_RULES`) and the
height each foot should reach, which the leg solve (`leg_solve.py`) then makes true.
"""

from __future__ import annotations

import mujoco
import numpy as np

ROOT_HEIGHT_RULES = ("contact_set", "foot_tracks", "contact_smooth")


def foot_geom_ids(model: mujoco.MjModel, foot_geom: str) -> np.ndarray:
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


def lowest_points(model: mujoco.MjModel, geom_ids: np.ndarray, xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
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
    return float(lowest_points(model, geom_ids, data.geom_xpos[geom_ids], data.geom_xmat[geom_ids]).min())


def foot_heights(model: mujoco.MjModel, qpos_frames: np.ndarray, foot_geoms: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(heights (T, F) m of each foot's lowest point, foot body positions (T, F, 3) m)."""
    data = mujoco.MjData(model)
    geoms = [foot_geom_ids(model, f) for f in foot_geoms]
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
    low = lowest_points(model, every, xpos, xmat)
    ends = np.cumsum([len(g) for g in geoms])
    h = np.stack([low[:, e - len(g):e].min(axis=1) for g, e in zip(geoms, ends)], axis=1)
    return h, pos


def root_offsets(h: np.ndarray, flags: np.ndarray, rule: str = "contact_set", loop: bool = False,
                 max_step: float | None = None) -> np.ndarray:
    """Per-frame vertical root offsets `[T]` (m) that put the feet on the floor, from each foot's
    lowest-point height `h [T, F]` (m, before the offset) and its contact flags `[T, F]` on the
    base character (Won & Lee 2019, METHOD.md A: after F, the feet touch the ground; this is the
    per-frame version of that pose solve's vertical root DOF, the legs' solve follows).

    "contact_set": minus the highest foot in contact at each frame, interpolated in time across
    frames without contact. "foot_tracks": each foot's height on its contact frames,
    interpolated in time across its swing, gives a track per foot; the offset is minus the
    highest track. Both put every contact foot at or below the floor (the leg solve lifts the
    rest); "contact_smooth": "contact_set" lowered where it must be so that it changes by at
    most `max_step` m between two frames (`lower_envelope`): where the longer leg takes over,
    the root rises at that rate after the switch instead of within a frame, and where the
    shorter one does, it sinks at that rate before it, the leg solve bending the stance leg
    meanwhile. It never lifts the root above "contact_set", so no stance foot floats; a stance
    foot may sink by up to the leg solve's tolerance (5 mm) where its leg is not solved.
    "foot_tracks" and "contact_smooth" are continuous when the contact set changes,
    "contact_set" is not. `loop`: the clip's
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
    if rule == "contact_smooth":
        if max_step is None or not max_step > 0:
            raise ValueError(f"the contact_smooth rule needs max_step > 0 (m per frame), not {max_step!r}")
        return lower_envelope(root_offsets(h, flags, "contact_set", loop), max_step, loop)
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


def lower_envelope(x: np.ndarray, max_step: float, loop: bool = False) -> np.ndarray:
    """The largest `y <= x` `[T]` that changes by at most `max_step` between neighbouring frames:
    y_t = min_j (x_j + max_step |t - j|), distances taken around the loop (period T - 1: the
    last frame repeats the first) for a looping clip. Linear time: a forward and a backward
    min-plus pass, twice around for a loop."""
    y = np.asarray(x, dtype=np.float64).copy()
    n = len(y)
    period = n - 1 if loop and n > 2 else None
    if period:
        ring = y[:period].copy()
        for _ in range(2):  # twice around: the wrap reaches every frame from every other
            for t in range(2 * period):
                ring[t % period] = min(ring[t % period], ring[(t - 1) % period] + max_step)
            for t in range(2 * period, 0, -1):
                ring[t % period] = min(ring[t % period], ring[(t + 1) % period] + max_step)
        y[:period] = ring
        y[period] = ring[0]
        return y
    for t in range(1, n):
        y[t] = min(y[t], y[t - 1] + max_step)
    for t in range(n - 2, -1, -1):
        y[t] = min(y[t], y[t + 1] + max_step)
    return y


def frame_distances(n: int, j: int, loop: bool = False) -> np.ndarray:
    """`[n]` how many frames each frame of a clip is from frame `j`; around the loop for a
    looping clip (period n - 1 frames: its last frame repeats the first)."""
    d = np.abs(np.arange(n) - j).astype(np.float64)
    period = n - 1 if loop and n > 2 else None
    if period:
        d = np.minimum(d % period, period - d % period)
    return d


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
