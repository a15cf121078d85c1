"""A user's MJCF file as a base character: the same shape operator F works on it.

Any file MuJoCo itself loads and compiles is accepted if a top-level body has a free joint (the
root); anything else is refused with one `ShapeError` line naming the file and the reason
(missing file, not XML or not MJCF, MuJoCo's own compiler error such as a missing mesh or
include, no free-jointed root body).

Several free bodies (a humanoid and a ball, or props around it): the character is the free body
with the most bodies below it (then the most degrees of freedom, then the first in the file).
Every other top-level body (props, mocap targets, static scenery bodies) is left out, and MuJoCo
deletes with them whatever refers to them (actuators, tendons, sensors, equalities, contact
pairs, keyframe entries); cameras and lights aimed at them stay, fixed. The world body's own
geoms, lights and cameras stay. So qpos[:7] is always the root's.

The spec is then normalised from its compiled model: body, geom, site, joint, camera and light
frames are written back as positions and quaternions relative to their body, `fromto` is
resolved, `<frame>`s become identities, so F sees one form whatever the file used (frames,
euler, axisangle, xyaxes, fromto, default classes, childclass, replicate, attach). Angles
stay in the file's own unit (only quaternions are written). Unnamed bodies get names
("body<k>"); `settotalmass` is baked into densities and explicit masses, so masses follow
volume under F. The normalised model is compared with MuJoCo's compile before normalising
(every body, geom, site, joint, camera and light pose, geom and site size, body mass), so a
construct this import does not handle (e.g. a mesh inside a scaled `<frame>`) is refused
rather than silently moved.

Long axes are inferred per body (the axis along which its children and geoms reach furthest).
A model with fluid (density > 0) or without gravity counts as a swimmer; any other is put on
the floor at its rest pose (no feet are known, so no pose solve). The file's own actuators,
options and timestep are kept; force limits scale like the presets'. Mesh and height-field
geoms are not rescaled, so a shape that scales a body carrying one is refused (operator.py).
MuJoCo's deprecation warnings about the file are not repeated while importing it.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import mujoco
import numpy as np

from common.characters.builder import BaseCharacter
from common.characters.errors import ShapeError
from common.characters.presets.swimmer_spaces import swimmer_spaces
from common.characters.shape_space import BodyPart, random_space, uniform_space

_FREE = mujoco.mjtJoint.mjJNT_FREE
_QUAT = mujoco.mjtOrientation.mjORIENTATION_QUAT
_MESH = mujoco.mjtGeom.mjGEOM_MESH
_PRIMITIVES = tuple(getattr(mujoco.mjtGeom, f"mjGEOM_{t}") for t in ("PLANE", "SPHERE", "CAPSULE", "ELLIPSOID",
                                                                   "CYLINDER", "BOX"))
TOLERANCE = 1e-6
"""Largest change normalisation may cause to a position or size [m], a quaternion component,
or a body mass [kg, relative above 1 kg]."""


def build(path: str, timestep_s: float | None = None) -> BaseCharacter:
    """Load, check and normalise a user MJCF (timestep_s is ignored: the file's own is kept
    unless `load_character(timestep_s=...)` overrides it). Raises ShapeError naming the file."""
    file = Path(path)
    name = repr(str(file))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # MuJoCo's deprecation notices about the file
        spec, model = _load(file, name)
        root = _choose_root(spec, model)
        if root is None:
            raise ShapeError(f"MJCF file {name} has no free-jointed root body: a character needs a top-level "
                             "body with a free joint (add <freejoint/> to its root body)")
        _name_bodies(spec)
        _bake_total_mass(spec)
        model = _leave_out_others(spec, root, name)
        _normalise(spec, model)
        normalised = _compile(spec, f"MJCF file {name} does not compile once normalised")
    _check_unchanged(model, normalised, name)
    model = normalised
    parts = tuple(BodyPart(b.name, ("body",), _long_axis(model, b.id)) for b in _subtree(root))
    swimmer = bool(model.opt.density > 0 or model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_GRAVITY
                   or not np.any(model.opt.gravity))
    spaces = {s.name: s for s in (random_space(parts), uniform_space(), *swimmer_spaces(None))}
    return BaseCharacter(preset=f"mjcf:{file}", spec=spec, parts=parts, spaces=spaces, is_swimmer=swimmer,
                         root_body=root.name, end_effector_bodies=tuple(p.name for p in parts if _is_leaf(model, p.name)))


def _load(file: Path, name: str) -> tuple[mujoco.MjSpec, mujoco.MjModel]:
    """The file's spec and MuJoCo's compile of it, or ShapeError with MuJoCo's reason on one line."""
    if not file.exists():
        raise ShapeError(f"MJCF file {name} does not exist; pass 'mjcf:/path/to/file.xml'")
    if not file.is_file():
        raise ShapeError(f"MJCF file {name} is not a file")
    try:
        spec = mujoco.MjSpec.from_file(str(file))
    except Exception as exc:  # MuJoCo raises a plain ValueError with its parser message
        raise ShapeError(f"MJCF file {name} does not parse as MJCF: {_one_line(exc)}") from exc
    return spec, _compile(spec, f"MJCF file {name} does not compile in MuJoCo")


def _leave_out_others(spec: mujoco.MjSpec, root: mujoco.MjsBody, name: str) -> mujoco.MjModel:
    """Delete every top-level body but `root` (MuJoCo deletes what refers to them, but for
    cameras and lights aimed at them: those are fixed where they are) and compile; refuse a
    character without geoms (nothing to stand on or collide with)."""
    others = [b for b in spec.worldbody.bodies if b.name != root.name]
    listed = ", ".join(repr(b.name) for b in others[:3]) + (", ..." if len(others) > 3 else "")
    gone = {b.name for top in others for b in _subtree(top)}
    for aimed in [*spec.cameras, *spec.lights]:
        if aimed.targetbody in gone:
            aimed.targetbody, aimed.mode = "", mujoco.mjtCamLight.mjCAMLIGHT_FIXED
    for body in others:
        spec.delete(body)
    model = _compile(spec, f"MJCF file {name} does not compile without its other top-level bodies ({listed})")
    if not np.any(model.geom_bodyid > 0):
        raise ShapeError(f"MJCF file {name}: the character (root body {root.name!r}) has no geoms to stand on "
                         "or collide with")
    return model


def _one_line(exc: Exception) -> str:
    """MuJoCo's multi-line compiler message (error, then element and line) on one line."""
    return " ".join(str(exc).split())


def _compile(spec: mujoco.MjSpec, what: str) -> mujoco.MjModel:
    try:
        return spec.compile()
    except Exception as exc:  # MuJoCo raises a plain ValueError with its compiler message
        raise ShapeError(f"{what}: {_one_line(exc)}") from exc


def _choose_root(spec: mujoco.MjSpec, model: mujoco.MjModel) -> mujoco.MjsBody | None:
    """The free top-level body with the most bodies, then degrees of freedom, below it (the
    first in the file on a tie); None if no top-level body has a free joint (MuJoCo allows
    free joints on top-level bodies only)."""
    best, best_key = None, None
    for body in spec.worldbody.bodies:
        if not any(j.type == _FREE for j in body.joints):
            continue
        inside = model.body_rootid == body.id
        key = (int(inside.sum()), int(model.body_dofnum[inside].sum()))
        if best_key is None or key > best_key:
            best, best_key = body, key
    return best


def _name_bodies(spec: mujoco.MjSpec) -> None:
    """Give unnamed bodies unique names "body<k>": shape parameters and F refer to bodies by name."""
    taken = {b.name for b in spec.bodies}
    for k, body in enumerate(spec.bodies):
        if body.name == "":
            name = f"body{k}"
            while name in taken:
                name += "_"
            body.name = name
            taken.add(name)


def _bake_total_mass(spec: mujoco.MjSpec) -> None:
    """Turn `<compiler settotalmass>` into scaled densities and explicit masses (as MuJoCo's
    deprecation notice advises), so a re-shaped character's mass follows its volume instead of
    being pulled back to the file's total."""
    target = spec.compiler.settotalmass
    if not target > 0:
        return
    spec.compiler.settotalmass = -1
    factor = target / float(spec.compile().body_mass.sum())
    for geom in spec.geoms:
        geom.density *= factor
        if np.isfinite(geom.mass):
            geom.mass *= factor
    for body in spec.bodies:
        if body.explicitinertial:
            body.mass *= factor
            body.inertia = np.asarray(body.inertia) * factor
            body.fullinertia = np.asarray(body.fullinertia) * factor


def _normalise(spec: mujoco.MjSpec, model: mujoco.MjModel) -> None:
    """Write every element's compiled pose (relative to its body) back into the spec and make
    every `<frame>` an identity; see the module docstring. `model` is the spec's last compile,
    so each element's `id` indexes it."""
    for body in spec.bodies:
        if body.id > 0:
            body.pos, body.quat = model.body_pos[body.id].copy(), model.body_quat[body.id].copy()
            body.alt.type = _QUAT
    for geom in spec.geoms:
        g = geom.id
        pos, quat = model.geom_pos[g].copy(), model.geom_quat[g].copy()
        if geom.type == _MESH:
            # NOTE: MuJoCo moves a mesh geom by its mesh's own offset (mesh_pos, mesh_quat) at
            # every compile, so the spec keeps the pose before that offset.
            mesh = model.geom_dataid[g]
            inverse = np.zeros(4)
            mujoco.mju_negQuat(inverse, model.mesh_quat[mesh])
            mujoco.mju_mulQuat(quat, model.geom_quat[g], inverse)
            offset = np.zeros(3)
            mujoco.mju_rotVecQuat(offset, model.mesh_pos[mesh], quat)
            pos = model.geom_pos[g] - offset
        if geom.type in _PRIMITIVES:
            geom.size = model.geom_size[g].copy()
            geom.meshname = ""  # a primitive fitted to a mesh keeps its fitted size
        geom.pos, geom.quat = pos, quat
        geom.alt.type = _QUAT
        geom.fromto = [np.nan] * 6
    for site in spec.sites:
        site.pos, site.quat = model.site_pos[site.id].copy(), model.site_quat[site.id].copy()
        site.size = model.site_size[site.id].copy()
        site.alt.type = _QUAT
        site.fromto = [np.nan] * 6
    for joint in spec.joints:
        joint.pos, joint.axis = model.jnt_pos[joint.id].copy(), model.jnt_axis[joint.id].copy()
    for cam in spec.cameras:
        cam.pos, cam.quat = model.cam_pos[cam.id].copy(), model.cam_quat[cam.id].copy()
        cam.alt.type = _QUAT
    for light in spec.lights:
        light.pos, light.dir = model.light_pos[light.id].copy(), model.light_dir[light.id].copy()
    for frame in spec.frames:
        frame.pos, frame.quat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
        frame.alt.type = _QUAT
        frame.scale = [1.0, 1.0, 1.0]


_POSITIONS = ("body_pos", "geom_pos", "geom_size", "site_pos", "site_size", "jnt_pos", "jnt_axis", "cam_pos",
              "light_pos", "light_dir")
_ROTATIONS = ("body_quat", "geom_quat", "site_quat", "cam_quat")


def _check_unchanged(before: mujoco.MjModel, after: mujoco.MjModel, name: str) -> None:
    """Refuse the file if normalising moved, turned, resized or re-weighed anything (a construct
    this import does not handle), naming the first field and element that changed."""
    for field in _POSITIONS + _ROTATIONS + ("body_mass",):
        a, b = getattr(before, field), getattr(after, field)
        if field in _ROTATIONS:
            err = np.minimum(np.abs(a - b), np.abs(a + b)).max(axis=1)  # q and -q are the same rotation
        elif field == "body_mass":
            err = np.abs(a - b) / np.maximum(np.abs(a), 1.0)
        else:
            err = np.abs(a - b).max(axis=1)
        if len(err) and err.max() > TOLERANCE:
            k = int(np.argmax(err))
            element = getattr(after, field.split("_")[0])(k).name or f"#{k}"
            raise ShapeError(f"MJCF file {name} cannot be imported: resolving its frames and orientations changed "
                             f"{field} of {element!r} by {err[k]:.3g}")


def _subtree(body: mujoco.MjsBody) -> list[mujoco.MjsBody]:
    out = [body]
    for child in body.bodies:
        out += _subtree(child)
    return out


def _is_leaf(model: mujoco.MjModel, name: str) -> bool:
    return not np.any(model.body_parentid[1:] == model.body(name).id)


def _long_axis(model: mujoco.MjModel, b: int) -> int:
    reach = np.zeros(3)
    for child in np.flatnonzero(model.body_parentid == b):
        if child != b:
            reach = np.maximum(reach, np.abs(model.body_pos[child]))
    for g in np.flatnonzero(model.geom_bodyid == b):
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, model.geom_quat[g])
        half = np.abs(rot.reshape(3, 3)) @ model.geom_aabb[g, 3:]
        reach = np.maximum(reach, np.abs(model.geom_pos[g]) + half)
    return int(np.argmax(reach))
