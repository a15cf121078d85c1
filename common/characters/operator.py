"""The shape operator F of Won & Lee 2019 (section 3; METHOD.md A): C = F(B, b).

`BaseGeometry.capture(spec)` records, once per base character, every length in the spec (body
offsets, geom sizes and offsets, joint anchors, sites, cameras, explicit masses and inertias,
actuator torque limits). `apply_scales` then writes absolute values for a new shape into the
same spec, so shapes never accumulate rounding and a spec can be re-shaped in place for
`MjSpec.recompile` (morph.py).

Per body b with 3-D scale s_b (body frame, from `ShapeSpace.segment_scales`):
- geoms of b: offset p -> diag(s_b) p; sizes along each geom axis a by ||diag(s_b) R_g[:, a]||
  (exact for axis-aligned geoms); capsule/cylinder radius by the geometric mean of the two
  cross axes; a sphere scaled unevenly becomes the ellipsoid it is;
- children of b: their offset (the joint anchor, "the joints that hang off it") -> diag(s_b) p;
- joints and sites of b: anchors scaled like geoms;
- mass: geoms keep their density, so mass follows volume and MuJoCo recomputes inertia from
  the geoms; explicit geom masses scale by the geom's volume ratio, explicit body inertials by
  prod(s_b) (mass) and prod(s_b) * s^2 (inertia, s^2 the mean squared cross scale);
- torque limits (actuator forcerange): times (m / m0) * (lbar / lbar0), lbar the mass-weighted
  mean bone-length scale. A gravity torque about a joint is mass x g x lever arm, so this keeps
  the limits proportional to the loads they hold; a uniform scale s gives s^4.
  PD gains kp, kd are not changed here (stable PD, METHOD.md A); `gains_follow_torque_limits`
  scales them (and the rotor inertia) with the torque limits when a task asks for it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

_SPHERE = mujoco.mjtGeom.mjGEOM_SPHERE
_ELLIPSOID = mujoco.mjtGeom.mjGEOM_ELLIPSOID
_ROUND = (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER)
_SCALABLE = (mujoco.mjtGeom.mjGEOM_BOX, _ELLIPSOID, _SPHERE, *_ROUND)


@dataclass(frozen=True)
class _GeomRec:
    geom: mujoco.MjsGeom
    type: int
    size: np.ndarray
    pos: np.ndarray
    rot: np.ndarray
    fromto: np.ndarray
    mass: float


@dataclass(frozen=True)
class _BodyRec:
    body: mujoco.MjsBody
    name: str
    parent: str
    pos: np.ndarray
    geoms: tuple[_GeomRec, ...]
    joints: tuple[tuple[mujoco.MjsJoint, np.ndarray], ...]
    sites: tuple[tuple[mujoco.MjsSite, np.ndarray, np.ndarray], ...]
    cameras: tuple[tuple[mujoco.MjsCamera, np.ndarray], ...]
    inertial: tuple[float, np.ndarray, np.ndarray] | None


@dataclass(frozen=True)
class BaseGeometry:
    """Every length of a base spec, captured once (see module docstring).

    rest_rot: body name -> [3, 3] body->world rotation at the rest pose.
    base_mass_kg: body name -> mass of the base body (from one compile of the base).
    """

    bodies: tuple[_BodyRec, ...]
    actuators: tuple[tuple[mujoco.MjsActuator, np.ndarray], ...]
    rest_rot: dict[str, np.ndarray]
    base_mass_kg: dict[str, float]

    @classmethod
    def capture(cls, spec: mujoco.MjSpec, base_model: mujoco.MjModel) -> "BaseGeometry":
        recs = []
        rest_rot = {}
        for body in spec.bodies:
            if body.name == "world" or body == spec.worldbody:
                continue
            parent = body.parent
            parent_rot = rest_rot.get(parent.name, np.eye(3))
            rest_rot[body.name] = parent_rot @ _rot(body.quat)
            geoms = tuple(
                _GeomRec(g, int(g.type), np.array(g.size), np.array(g.pos), _rot(g.quat), np.array(g.fromto), float(g.mass))
                for g in body.geoms
            )
            inertial = None
            if body.explicitinertial:
                inertial = (float(body.mass), np.array(body.inertia), np.array(body.fullinertia))
            recs.append(_BodyRec(
                body, body.name, parent.name, np.array(body.pos), geoms,
                tuple((j, np.array(j.pos)) for j in body.joints),
                tuple((s, np.array(s.pos), np.array(s.size)) for s in body.sites),
                tuple((c, np.array(c.pos)) for c in body.cameras),
                inertial,
            ))
        actuators = tuple((a, np.array(a.forcerange)) for a in spec.actuators)
        masses = {
            base_model.body(i).name: float(base_model.body_mass[i]) for i in range(1, base_model.nbody)
        }
        return cls(tuple(recs), actuators, rest_rot, masses)

    def torque_scale(self, scales: Mapping[str, np.ndarray], long_axis: Mapping[str, int]) -> float:
        """(m / m0) * (lbar / lbar0): the torque-limit factor of the module docstring."""
        m0 = sum(self.base_mass_kg.values())
        m = sum(self.base_mass_kg[b] * float(np.prod(scales[b])) for b in self.base_mass_kg)
        lbar = sum(self.base_mass_kg[b] * float(scales[b][long_axis[b]]) for b in self.base_mass_kg) / m0
        return (m / m0) * lbar


def apply_scales(spec: mujoco.MjSpec, base: BaseGeometry, scales: Mapping[str, np.ndarray],
                 torque_factor: float) -> None:
    """Write the shape given by per-body scales [3] into `spec` (in place; absolute values from
    `base`, so calling it again with other scales is a clean re-shape). Geoms F cannot rescale
    keep their size: check `unscalable` first."""
    one = np.ones(3)
    for rec in base.bodies:
        s = np.asarray(scales.get(rec.name, one), dtype=float)
        s_parent = np.asarray(scales.get(rec.parent, one), dtype=float)
        if rec.parent != "world":
            rec.body.pos = s_parent * rec.pos
        for g in rec.geoms:
            _scale_geom(g, s)
        for joint, pos in rec.joints:
            joint.pos = s * pos
        for site, pos, size in rec.sites:
            site.pos = s * pos
            site.size = size * float(np.cbrt(np.prod(s)))
        for cam, pos in rec.cameras:
            # NOTE: the tracking camera must not move with body scale (it frames the whole body).
            if cam.name != "track":
                cam.pos = s * pos
        if rec.inertial is not None:
            mass, inertia, full = rec.inertial
            vol = float(np.prod(s))
            cross = float(np.mean(s**2))
            rec.body.mass = mass * vol
            rec.body.inertia = inertia * vol * cross
            if np.all(np.isfinite(full)):
                rec.body.fullinertia = full * vol * cross
    for act, forcerange in base.actuators:
        act.forcerange = forcerange * torque_factor


def unscalable(base: BaseGeometry, scales: Mapping[str, np.ndarray]) -> tuple[str, str] | None:
    """(body, geom kind) of the first body that carries a geom F cannot rescale (a mesh or
    height field, e.g. from a user's MJCF) yet would get a scale other than 1; None if none."""
    for rec in base.bodies:
        fixed = [g for g in rec.geoms if g.type not in _SCALABLE]
        if fixed and not np.allclose(scales.get(rec.name, 1.0), 1.0):
            return rec.name, mujoco.mjtGeom(fixed[0].type).name.removeprefix("mjGEOM_").lower()
    return None


def gains_follow_torque_limits(model: mujoco.MjModel, base_model: mujoco.MjModel) -> float:
    """Scale a shaped character's PD gains kp, kd and rotor inertias (armature) by the factor its
    torque limits got (`torque_scale`), in place, from the base character's values (so calling it
    twice changes nothing); returns the factor.

    NOTE: METHOD.md A keeps one set of gains for every shape (stable PD), which assumes torque is
    not limited. Here the limits follow the loads (m/m0 * lbar/lbar0: 1.5% of the base's on the
    smallest lower biped, 10.5x on the largest) while kp stayed 500 N m/rad, so a small body's PD
    hits its limit at a few mrad of error: measured with zero actions over 20 control steps,
    24% of its actuators at the limit against 0.3% on the base shape, and 0% with the gains
    scaled. With kp, kd and the armature all times the same factor, every body saturates at the
    same angle error and keeps the base's kp/kd and kp/armature ratios (the step's stability)."""
    if model.nu == 0:
        return 1.0
    f = float(model.actuator_forcerange[0, 1] / base_model.actuator_forcerange[0, 1])
    model.actuator_gainprm[:, 0] = base_model.actuator_gainprm[:, 0] * f
    model.actuator_biasprm[:, 1:3] = base_model.actuator_biasprm[:, 1:3] * f
    model.dof_armature[:] = base_model.dof_armature * f
    return f


def _scale_geom(g: _GeomRec, s: np.ndarray) -> None:
    geom = g.geom
    geom.pos = s * g.pos
    eff = np.linalg.norm(s[:, None] * g.rot, axis=0)  # scale along each geom axis
    if np.all(np.isfinite(g.fromto)) and not np.all(g.fromto == 0):
        geom.fromto = np.concatenate([s * g.fromto[:3], s * g.fromto[3:]])
    if g.type not in _SCALABLE:
        return  # planes, meshes, height fields: see `unscalable`
    size = g.size.copy()
    if g.type == _SPHERE:
        if np.ptp(eff) < 1e-9:
            geom.type = _SPHERE
            size[0] = g.size[0] * eff[0]
        else:
            geom.type = _ELLIPSOID
            size = g.size[0] * eff
    elif g.type in _ROUND:
        size[0] = g.size[0] * np.sqrt(eff[0] * eff[1])
        size[1] = g.size[1] * eff[2]
    else:
        size = g.size * eff
    geom.size = size
    if np.isfinite(g.mass):
        geom.mass = g.mass * float(np.prod(eff))


def _rot(quat) -> np.ndarray:
    q = np.asarray(quat, dtype=float)
    return Rotation.from_quat(q / np.linalg.norm(q), scalar_first=True).as_matrix()
