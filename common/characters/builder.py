"""Shared pieces for building base characters with `mujoco.MjSpec` (no XML templating).

Actuation choice (DESIGN.md "PD must run inside MuJoCo"): every actuated DOF gets a MuJoCo
`position` actuator with the base character's gains, kp as `gainprm` and kd as `kv`, on a
ball joint one actuator per body axis (joint transmission with `gear` = that axis: MuJoCo then
uses the axis component of the joint's rotation vector as the actuator length). The model uses
the `implicitfast` integrator, which integrates the velocity term kv implicitly, so
`tau = kp (qbar - q) - kd qdot` with qdot taken at the end of the step: the stable PD of
Tan et al. 2011 in its damping part (METHOD.md A). With kd = kp/10 the step stays stable however
light a scaled segment gets (the explicit stiffness step is bounded by h*kp/kd, not by the
segment inertia), so one set of gains, tuned on the base character, serves every shape.
Ball joints keep quaternions in qpos, so mocap clips drop in by `qpos` assignment. Measured
alternatives: a numpy PD per substep cost 46% throughput; explicit Euler with kv diverged.
Every actuated DOF has a rotor inertia `armature` of ARMATURE_KG_M2: without it the biped's
light hands and clavicles diverged under random PD targets at 480 and 600 Hz (measured: 2 of
12 extreme biped shapes at 1e-3, 0 of 24 at 1e-2); 1e-2 kg m^2 is the usual value of MuJoCo's
humanoid models and slows only the lightest segments (hands, small scaled limbs).
Joint limits: hinge joints keep theirs; ball joints get none (a cone limit is costly and
the PD target range `ctrlrange` already bounds where the policy can push them).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from common.characters.shape_space import BodyPart, ShapeSpace

GEOM_TYPES = {
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
    "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
    "ellipsoid": mujoco.mjtGeom.mjGEOM_ELLIPSOID,
    "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
}
BODY_RGBA = (0.47, 0.55, 0.69, 1.0)
FLOOR_NAME = "floor"
ARMATURE_KG_M2 = 1e-2
WATER_DENSITY_KG_M3 = 1000.0
WATER_VISCOSITY_PA_S = 0.0009


@dataclass(frozen=True)
class JointDef:
    """One actuated joint. kind: "ball" (3 DOF) or "hinge" (1 DOF about `axis`, body frame).

    ranges: PD target range per DOF in rad ((lo, hi) once for a hinge, three times for the
    ball's body x, y, z axes); a hinge's range is also its joint limit. kp [N m/rad],
    kd [N m s/rad]: base character gains, never changed by shape. tau_max [N m]: base torque
    limit, scaled by shape (operator.torque_scale). pos: joint anchor in the body frame [m].
    """

    name: str
    kind: str
    kp: float
    kd: float
    tau_max: float
    ranges: tuple[tuple[float, float], ...]
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class GeomDef:
    """One collision/inertia geom. size follows MuJoCo (half-sizes; radius, half-length).
    mass_kg: the base mass this geom carries; converted to a density so that scaled copies
    keep the density and their mass follows their volume."""

    kind: str
    size: tuple[float, ...]
    mass_kg: float
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    name: str | None = None


@dataclass(frozen=True)
class BaseCharacter:
    """A base character B before the shape operator: its spec plus what F and the tools need.

    legs: (hip body, foot geom) per leg, in the order of `Character.leg_lengths_m`.
    root_z_m: root height to start the pose solve from. track_body: body the camera follows.
    """

    preset: str
    spec: mujoco.MjSpec
    parts: tuple[BodyPart, ...]
    spaces: dict[str, ShapeSpace]
    foot_geoms: tuple[str, ...] = ()
    legs: tuple[tuple[str, str], ...] = ()
    end_effector_bodies: tuple[str, ...] = ()
    is_swimmer: bool = False
    root_body: str = ""
    extras: dict = field(default_factory=dict)


def volume(kind: str, size) -> float:
    """Geom volume [m^3] from MuJoCo sizes."""
    s = np.asarray(size, dtype=float)
    if kind == "box":
        return 8.0 * s[0] * s[1] * s[2]
    if kind == "sphere":
        return 4.0 / 3.0 * np.pi * s[0] ** 3
    if kind == "ellipsoid":
        return 4.0 / 3.0 * np.pi * s[0] * s[1] * s[2]
    if kind == "capsule":
        return np.pi * s[0] ** 2 * 2.0 * s[1] + 4.0 / 3.0 * np.pi * s[0] ** 3
    if kind == "cylinder":
        return np.pi * s[0] ** 2 * 2.0 * s[1]
    raise ValueError(f"no volume formula for geom kind {kind!r}")


def new_world(name: str, timestep_s: float, swimmer: bool) -> mujoco.MjSpec:
    """An empty world: floor with a checker texture, light, options.

    Swimmers float in water (MuJoCo's fluid model: `density` and `viscosity` of water, no
    gravity, i.e. neutral buoyancy) above a floor they cannot touch (contype 0): it is only
    there so a picture shows where they are.
    """
    spec = mujoco.MjSpec()
    spec.modelname = name
    # NOTE: MjSpec defaults to degrees for angles (joint ranges); everything here is radians.
    spec.compiler.degree = False
    spec.option.timestep = timestep_s
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    if swimmer:
        spec.option.gravity = [0.0, 0.0, 0.0]
        spec.option.density = WATER_DENSITY_KG_M3
        spec.option.viscosity = WATER_VISCOSITY_PA_S
    spec.visual.global_.offwidth = 1280
    spec.visual.global_.offheight = 960
    spec.add_texture(
        name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.2, 0.3, 0.4], rgb2=[0.1, 0.15, 0.2], width=512, height=512,
    )
    spec.add_material(name="grid", texrepeat=[1.0, 1.0], reflectance=0.1, texuniform=True).textures[
        mujoco.mjtTextureRole.mjTEXROLE_RGB
    ] = "grid"
    floor = spec.worldbody.add_geom(
        name=FLOOR_NAME, type=mujoco.mjtGeom.mjGEOM_PLANE, size=[50.0, 50.0, 0.1], material="grid"
    )
    if swimmer:
        floor.contype = 0
        floor.conaffinity = 0
    spec.worldbody.add_light(name="sun", pos=[0.0, 0.0, 6.0], dir=[0.0, 0.2, -1.0],
                              type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, castshadow=False)
    return spec


def add_body(parent: mujoco.MjsBody, name: str, pos, geoms: list[GeomDef], joints: list[JointDef] = (),
             swimmer: bool = False, free: bool = False) -> mujoco.MjsBody:
    """Add one segment: body frame at the joint anchor `pos` (parent frame, m), its geoms
    (density from each GeomDef's mass and volume) and its joints. Character geoms collide
    with the floor only (contype 1, conaffinity 0; the floor has both), never with each
    other: self-collision is left out because contacts dominate the step cost (DESIGN.md)."""
    body = parent.add_body(name=name, pos=list(pos))
    if free:
        body.add_freejoint(name="root")
    for j in joints:
        jt = body.add_joint(name=j.name, pos=list(j.pos))
        jt.armature = ARMATURE_KG_M2
        if j.kind == "ball":
            jt.type = mujoco.mjtJoint.mjJNT_BALL
        else:
            jt.type = mujoco.mjtJoint.mjJNT_HINGE
            jt.axis = list(j.axis)
            jt.range = list(j.ranges[0])
            jt.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    for k, g in enumerate(geoms):
        geom = body.add_geom(
            name=g.name or (name if k == 0 else f"{name}_{k}"), type=GEOM_TYPES[g.kind],
            size=list(g.size) + [0.0] * (3 - len(g.size)), pos=list(g.pos), quat=list(g.quat), rgba=list(BODY_RGBA),
        )
        geom.density = g.mass_kg / volume(g.kind, g.size)
        geom.contype = 1
        geom.conaffinity = 0
        if swimmer:
            # NOTE: fluid_ellipsoid switches this geom to MuJoCo's ellipsoid lift/drag model.
            geom.fluid_ellipsoid = 1.0
    return body


def add_pd_actuators(spec: mujoco.MjSpec, joints: list[JointDef]) -> None:
    """Position actuators (PD, see module docstring) for `joints`, named `<joint>` for a hinge
    and `<joint>_x|_y|_z` for a ball's three body axes, in joint order."""
    for j in joints:
        axes = [(j.name, None)] if j.kind == "hinge" else [(f"{j.name}_{a}", k) for k, a in enumerate("xyz")]
        for (name, k), rng in zip(axes, j.ranges):
            act = spec.add_actuator(name=name, target=j.name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
            if k is not None:
                gear = np.zeros(6)
                gear[k] = 1.0
                act.gear = gear
            act.set_to_position(kp=j.kp, kv=j.kd)
            act.ctrlrange = list(rng)
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.forcerange = [-j.tau_max, j.tau_max]
            act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE


def add_tracking_camera(root: mujoco.MjsBody, distance_m: float, height_m: float) -> None:
    """A camera riding with the root's centre of mass (orientation fixed in the world), looking
    at it from the front-left, for viewers; render.py places its own camera from the extent."""
    eye = np.array([distance_m * 0.6, -distance_m * 0.8, height_m])
    fwd = -eye / np.linalg.norm(eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    root.add_camera(name="track", mode=mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM, pos=list(eye),
                    xyaxes=list(right) + list(up))


def quat_from_matrix(mat: np.ndarray) -> list[float]:
    """Rotation matrix [3, 3] -> MuJoCo quaternion (w, x, y, z); the nearest rotation is used
    (source data sometimes rounds its matrices) and a reflection is turned into a rotation by
    flipping one axis, which a box, ellipsoid or capsule does not notice."""
    mat = np.asarray(mat, dtype=float)
    if np.linalg.det(mat) < 0:
        mat = mat @ np.diag([1.0, 1.0, -1.0])
    return list(Rotation.from_matrix(mat).as_quat(scalar_first=True))
