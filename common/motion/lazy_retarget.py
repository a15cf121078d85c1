"""A clip retargeted onto a shaped body frame by frame, as it is played (`LazyRetargetedMotion`).

`retarget.retarget_frames` then `clean.clean_motion(..., floor=True)` make every frame of a clip
on a body at once: three loops of MuJoCo kinematics over all frames (foot heights, the leg
solve, the floor lift), 30-100 ms on a 5 s take, nearly all of it in frames an episode that
starts somewhere in the clip and ends a second later never reads. With the default rule
("contact_set", a clip played once through, no body clearance) every step of that pipeline is
per frame, bar one bounded look-around:

- root stride and height scaling: per frame (about frame 0 and the clip's floor on the base,
  both known up front);
- foot heights: per frame (the pose before the root offset);
- the root offset of a frame with a foot in contact: minus its highest contact foot, per
  frame; of a frame without: `np.interp` between the contact frames either side (held from the
  first or last contact frame at the ends) -- so a frame needs the foot heights of the nearest
  contact frame before and after it too;
- the leg solve: per frame and foot (its knee bounds, `leg_solve.bend_side_bounds`, read the
  clip's hinge angles over all frames, which no shape changes: computed once up front);
- the floor lift (`clean.floor_offsets`): per frame.

So a frame costs the same whenever it is made, and made alone it is the same number, bit for
bit, as in the whole clip's pass (the same operations on the same values, `np.interp` on the
same two bracketing points): `FrameRetarget.fill` makes the frames a time span needs, once,
and `LazyRetargetedMotion` calls it before every read. Another rule ("foot_tracks",
"contact_smooth"), a looping clip, a body clearance or a clip with no contact at all reads
global statistics of the clip (a lower envelope, a percentile, the loop's wrap): `fits` says
when, and the caller retargets eagerly then.
"""

from __future__ import annotations

import mujoco
import numpy as np

from common.motion.clip import Clip
from common.motion.leg_solve import Leg
from common.motion.reference import CharacterMotion
from common.motion.retarget import ContactPhases
from common.motion.retarget_config import RetargetConfig
from common.motion.root_height import foot_geom_ids


def fits(cfg: RetargetConfig, loop: bool, contacts: ContactPhases) -> bool:
    """Whether frames of a clip can be retargeted one by one (module docstring)."""
    return (cfg.root_height == "contact_set" and not loop and not cfg.body_clearance_m > 0
            and bool(contacts.flags.any()))


class LowestPoints:
    """`root_height.lowest_points` of one set of geoms, its per-kind selections made once: the
    same operations on the same values (so the same numbers), without re-deriving the selections
    on every call (the leg solve asks for one foot's lowest point a dozen times per frame)."""

    def __init__(self, model: mujoco.MjModel, geom_ids: np.ndarray):
        self.ids = np.asarray(geom_ids, dtype=np.int64)
        kinds = model.geom_type[self.ids]
        self.groups = []
        for kind in set(kinds.tolist()):
            sel = kinds == kind
            where = slice(None) if sel.all() else np.flatnonzero(sel)
            self.groups.append((kind, where, model.geom_size[self.ids[sel]], model.geom_rbound[self.ids[sel]]))

    def __call__(self, xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
        """Heights `[..., G]` of the geoms' lowest points in poses `xpos` `[..., G, 3]`, `xmat` `[..., G, 9]`."""
        r = xmat.reshape(*xmat.shape[:-1], 3, 3)[..., 2, :]
        drop = np.empty(r.shape[:-1])
        for kind, sel, size, rbound in self.groups:
            rk = r[..., sel, :]
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
                drop[..., sel] = rbound
        return xpos[..., 2] - drop


class LegSolver:
    """`leg_solve.lift_foot` and `retarget_frames`' rounds around it for one foot on one MjData,
    its buffers, views of the data and the leg's index arithmetic made once: the same MuJoCo and
    numpy operations on the same values in the same order (so the same numbers, held by the
    tests against `retarget_frames`), with less Python around each Gauss-Newton step (no
    allocations, no `np.clip` wrapper, MjData views read once, the leg's DOF columns a slice)."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, leg: Leg, geom_ids: np.ndarray, cfg: RetargetConfig):
        self.model, self.data, self.leg, self.cfg = model, data, leg, cfg
        self.lowest = LowestPoints(model, geom_ids)
        self.geoms = self.lowest.ids
        boxes = bool(np.all(model.geom_type[self.geoms] == mujoco.mjtGeom.mjGEOM_BOX))
        self.box_size = model.geom_size[self.geoms] if boxes else None
        dofs = leg.dofs
        contiguous = len(dofs) > 0 and np.array_equal(dofs, np.arange(dofs[0], dofs[0] + len(dofs)))
        self.cols = slice(int(dofs[0]), int(dofs[0]) + len(dofs)) if contiguous else dofs
        n = len(dofs)
        self.jacp, self.jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        self.err, self.err_r, self.qv = np.zeros(6), np.zeros(3), np.zeros(model.nv)
        self.damping = cfg.ik_damping * np.eye(n)
        self.jac, self.step = np.zeros((6, n)), np.zeros(n)
        self.qpos, self.xpos, self.xquat = data.qpos, data.xpos, data.xquat
        self.geom_xpos, self.geom_xmat = data.geom_xpos, data.geom_xmat
        self.hinge_qpos, self.hinge_lo, self.hinge_hi = leg.hinge_qpos, leg.hinge_lo, leg.hinge_hi

    def lowest_z(self) -> float:
        """`root_height.lowest_z` of the foot in the data's current pose (boxes, the usual feet:
        `lowest_points`' box arithmetic on the same `[G, 3]` arrays, without its dispatch)."""
        if self.box_size is None:
            return float(self.lowest(self.geom_xpos[self.geoms], self.geom_xmat[self.geoms]).min())
        r = self.geom_xmat[self.geoms].reshape(-1, 3, 3)[:, 2, :]
        return float((self.geom_xpos[self.geoms][:, 2] - np.add.reduce(np.abs(r) * self.box_size, axis=-1)).min())

    def clamp_hinges(self) -> None:
        """`Leg.clamp_hinges` (np.clip's arithmetic: the larger of the value and its lower bound,
        then the smaller of that and the upper bound)."""
        q = self.qpos
        q[self.hinge_qpos] = np.minimum(np.maximum(q[self.hinge_qpos], self.hinge_lo), self.hinge_hi)

    def solve(self, q: np.ndarray, goal: float, h: float) -> None:
        """`retarget_frames`' leg solve of this foot on pose `q` `[nq]` (in place): lift it from
        height `h` to `goal`, measure again and lift the rest, a few rounds at most."""
        m, d, cfg, leg = self.model, self.data, self.cfg, self.leg
        self.qpos[:] = q
        depth = goal - h
        leg.unstraighten(d)
        for attempt in range(4):
            before = depth
            self.lift(depth)
            depth = goal - self.lowest_z()
            if depth < cfg.ik_tolerance_m:
                break
            if depth > before - 1e-3:
                kick = np.zeros(m.nv)
                side = leg.side_by_dof
                kick[leg.dofs] = np.where(side != 0.0, 0.2 * side, 0.1 if attempt % 2 == 0 else -0.2)
                mujoco.mj_integratePos(m, self.qpos, kick, 1.0)
                self.clamp_hinges()
                mujoco.mj_kinematics(m, d)
                depth = goal - self.lowest_z()
        q[:] = self.qpos

    def lift(self, lift_m: float) -> None:
        """`leg_solve.lift_foot` of this foot by `lift_m` (m)."""
        m, d, body, cols = self.model, self.data, self.leg.body, self.cols
        xpos, xquat, jacp, jacr, err, err_r, jac, step, qv = (self.xpos, self.xquat, self.jacp, self.jacr, self.err,
                                                              self.err_r, self.jac, self.step, self.qv)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        target_p = xpos[body] + np.array([0.0, 0.0, lift_m])
        target_q = xquat[body].copy()
        w = self.cfg.ik_orientation_weight_m
        for _ in range(self.cfg.ik_iterations):
            err[:3] = target_p - xpos[body]
            if err[0] * err[0] + err[1] * err[1] + err[2] * err[2] < 1e-8:
                break
            mujoco.mj_jacBody(m, d, jacp, jacr, body)
            mujoco.mju_subQuat(err_r, target_q, xquat[body])
            err[3:] = w * err_r
            jac[:3] = jacp[:, cols]
            jac[3:] = w * jacr[:, cols]
            normal = jac.T @ jac + self.damping
            mujoco.mju_cholFactor(normal, 0.0)
            mujoco.mju_cholSolve(step, normal, jac.T @ err)
            qv[cols] = step
            mujoco.mj_integratePos(m, self.qpos, qv, 1.0)
            self.clamp_hinges()
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)


class FrameRetarget:
    """`retarget.retarget_frames` of qpos frames `[T, nq]` at `fps` (the clip played on the base
    character, not looping) onto `model`, and with `floor` `clean.floor_offsets` of the result,
    frame by frame on demand (`fill`): `out` `[T, nq]` holds the finished frames where `done`,
    the stride- and height-scaled frames elsewhere. `data`: scratch MjData of `model` (only used
    inside `fill`)."""

    def __init__(self, qpos: np.ndarray, fps: float, model: mujoco.MjModel, foot_geoms: tuple[str, ...],
                 leg_ratio: float, contacts: ContactPhases, cfg: RetargetConfig, floor: bool, data: mujoco.MjData):
        if not fits(cfg, False, contacts):
            raise ValueError("frame by frame retargeting needs the contact_set rule, no body clearance and some contact")
        self.model, self.cfg, self.floor, self.data, self.fps = model, cfg, floor, data, float(fps)
        self.flags = contacts.flags
        pre = np.array(qpos, dtype=np.float64)  # the same element operations as retarget_frames on a copy
        xy0 = pre[0, :2].copy()
        pre[:, :2] = xy0 + leg_ratio * (pre[:, :2] - xy0)
        pre[:, 2] = leg_ratio * (pre[:, 2] - contacts.ground_m)
        self.pre = pre
        """The frames scaled for the body, before the root offset (what the foot heights are of)."""
        self.out = pre.copy()
        self.done = np.zeros(len(pre), dtype=bool)
        self.h = np.zeros(self.flags.shape)
        self.h_done = np.zeros(len(pre), dtype=bool)
        self.contact_frames = np.flatnonzero(self.flags.any(axis=1))
        geoms = [foot_geom_ids(model, f) for f in foot_geoms]
        self.solvers = [LegSolver(model, data, Leg.of(model, int(model.geom(f).bodyid[0]), pre), g, cfg)
                        for f, g in zip(foot_geoms, geoms)]
        self.feet = LowestPoints(model, np.concatenate(geoms))
        self.foot_cols = [slice(e - len(g), e) for g, e in zip(geoms, np.cumsum([len(g) for g in geoms]))]
        self.body = LowestPoints(model, np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] > 0], dtype=np.int64))

    def __len__(self) -> int:
        return len(self.pre)

    @property
    def complete(self) -> bool:
        return bool(self.done.all())

    def fill(self, lo: int = 0, hi: int | None = None) -> None:
        """Make frames [lo, hi) (all by default) that are not made yet."""
        hi = len(self) if hi is None else hi
        k = np.flatnonzero(~self.done[lo:hi]) + lo
        if not len(k):
            return
        c = self.contact_frames
        # the contact frames bracketing k: the root offset's interpolation reads only those
        a = max(int(np.searchsorted(c, k[0], side="right")) - 1, 0)
        b = min(int(np.searchsorted(c, k[-1], side="left")), len(c) - 1)
        xp = c[a:b + 1]
        self._foot_heights(np.union1d(k, xp))
        highest = np.where(self.flags[xp], self.h[xp], -np.inf).max(axis=1)
        # NOTE: as many points asked as given at least, as in the whole clip's call (np.interp
        # may precompute its slopes when asked for more points than it is given)
        dz = -np.interp(np.concatenate([k, xp]), xp, highest)[:len(k)]
        q = self.pre[k]
        q[:, 2] += dz
        h = self.h[k] + dz[:, None]
        goal = np.maximum(h, 0.0)
        for j, i in zip(*np.nonzero(goal - h > self.cfg.ik_tolerance_m)):
            self.solvers[i].solve(q[j], float(goal[j, i]), float(h[j, i]))
        if self.floor:
            q[:, 2] += np.maximum(0.0, -self._lowest(q))
        self.out[k] = q
        self.done[k] = True

    def _poses(self, q: np.ndarray, geoms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions `[K, G, 3]` and rotation matrices `[K, G, 9]` of geoms `geoms` in poses q `[K, nq]`
        (every geom's copied per frame, one block copy, and `geoms` taken out of them at once)."""
        m, d = self.model, self.data
        d_qpos, d_xpos, d_xmat = d.qpos, d.geom_xpos, d.geom_xmat
        xpos, xmat = np.empty((len(q), m.ngeom, 3)), np.empty((len(q), m.ngeom, 9))
        for r in range(len(q)):
            d_qpos[:] = q[r]
            mujoco.mj_kinematics(m, d)
            xpos[r], xmat[r] = d_xpos, d_xmat
        return xpos[:, geoms], xmat[:, geoms]

    def _foot_heights(self, frames: np.ndarray) -> None:
        """`root_height.foot_heights` of the scaled frames `frames` not measured yet, into `h`."""
        frames = frames[~self.h_done[frames]]
        if not len(frames):
            return
        low = self.feet(*self._poses(self.pre[frames], self.feet.ids))
        self.h[frames] = np.stack([low[:, cols].min(axis=1) for cols in self.foot_cols], axis=1)
        self.h_done[frames] = True

    def _lowest(self, q: np.ndarray) -> np.ndarray:
        """`clean.lowest_geom_heights` of frames q `[K, nq]`."""
        return self.body(*self._poses(q, self.body.ids)).min(axis=1)


class LazyRetargetedMotion(CharacterMotion):
    """A `CharacterMotion` whose frames are those of a `FrameRetarget`, each made the first time
    a read needs it: `qpos` (and so `qvel_at`, `state`) makes the frames its times interpolate
    between, `qpos_frames` all of them. NOTE: `frames` (the Clip) holds unmade frames as the
    scaled ones until a read makes them; read through the methods."""

    def __init__(self, clip: Clip, model: mujoco.MjModel, frames: FrameRetarget,
                 end_effector_bodies: tuple[str, ...] = ()):
        super().__init__(clip, model, frames.out, end_effector_bodies, fps=frames.fps)
        self.retarget = frames

    def _cover(self, t_s: float | np.ndarray) -> None:
        if self.retarget.complete:
            return
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        if not len(t):
            return
        # the frames kinematics.sample interpolates between (a clip played once: times clamped)
        f = np.clip(t, 0.0, self.frames.duration_s) * self.frames.fps
        n = len(self.retarget)
        lo = min(max(int(np.floor(f.min())), 0), n - 1)
        hi = min(max(int(np.floor(f.max())), 0) + 2, n)
        self.retarget.fill(lo, hi)

    def qpos(self, t_s: float | np.ndarray) -> np.ndarray:
        self._cover(t_s)
        return super().qpos(t_s)

    @property
    def qpos_frames(self) -> np.ndarray:
        self.retarget.fill()
        return super().qpos_frames
