"""A user's MJCF file as a base character: the same shape operator F works on it.

Requirements: the file parses and compiles, and a top-level body has a free joint (the root).
The spec is normalised once from its compiled model (body, geom, joint and site frames written
back as plain positions and quaternions, `fromto` resolved), so F sees one form whatever the
file used (euler, axisangle, fromto, angle units). Long axes are inferred per body (the axis
along which its children and geoms reach furthest). A model with fluid (density > 0) or without
gravity counts as a swimmer; any other is put on the floor at its rest pose (no feet are
known, so no pose solve). The file's own actuators are kept; their force limits scale like the
presets'. Meshes and height fields are not rescaled (documented limitation).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from common.characters.builder import BaseCharacter
from common.characters.errors import ShapeError
from common.characters.presets.swimmer_spaces import swimmer_spaces
from common.characters.shape_space import BodyPart, random_space, uniform_space


def build(path: str, timestep_s: float | None = None) -> BaseCharacter:
    """Load, check and normalise a user MJCF (timestep_s is ignored: the file's own is kept
    unless `load_character(timestep_s=...)` overrides it)."""
    file = Path(path)
    if not file.is_file():
        raise ShapeError(f"MJCF file {str(file)!r} does not exist; pass 'mjcf:/path/to/file.xml'")
    try:
        spec = mujoco.MjSpec.from_file(str(file))
        model = spec.compile()
    except Exception as exc:
        raise ShapeError(f"MJCF file {str(file)!r} does not parse or compile: {exc}") from exc
    roots = [b for b in spec.worldbody.bodies if any(j.type == mujoco.mjtJoint.mjJNT_FREE for j in b.joints)]
    if not roots:
        raise ShapeError(f"MJCF file {str(file)!r} has no top-level body with a free joint; a character needs a "
                         "free root (add <freejoint/> to its root body)")
    root = roots[0]
    for k, body in enumerate(spec.bodies):
        if body.name == "":
            body.name = f"body{k}"
    _normalise(spec, model)
    spec.compiler.degree = False
    model = spec.compile()
    parts = tuple(BodyPart(b.name, ("body",), _long_axis(model, model.body(b.name).id)) for b in _subtree(root))
    swimmer = bool(model.opt.density > 0 or model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_GRAVITY
                   or not np.any(model.opt.gravity))
    spaces = {s.name: s for s in (random_space(parts), uniform_space(), *swimmer_spaces(None))}
    return BaseCharacter(preset=f"mjcf:{file}", spec=spec, parts=parts, spaces=spaces, is_swimmer=swimmer,
                         root_body=root.name, end_effector_bodies=tuple(p.name for p in parts if _is_leaf(model, p.name)))


def _subtree(body: mujoco.MjsBody) -> list[mujoco.MjsBody]:
    out = [body]
    for child in body.bodies:
        out += _subtree(child)
    return out


def _is_leaf(model: mujoco.MjModel, name: str) -> bool:
    return not np.any(model.body_parentid[1:] == model.body(name).id)


def _normalise(spec: mujoco.MjSpec, model: mujoco.MjModel) -> None:
    quat_type = mujoco.mjtOrientation.mjORIENTATION_QUAT
    for body in spec.bodies:
        if body.name == "world":
            continue
        b = model.body(body.name).id
        body.pos, body.quat = model.body_pos[b].copy(), model.body_quat[b].copy()
        body.alt.type = quat_type
        for geom, gid in zip(body.geoms, _ids(model, model.geom_bodyid, b)):
            geom.pos, geom.quat = model.geom_pos[gid].copy(), model.geom_quat[gid].copy()
            geom.alt.type = quat_type
            geom.fromto = [np.nan] * 6
            if geom.type not in (mujoco.mjtGeom.mjGEOM_MESH, mujoco.mjtGeom.mjGEOM_HFIELD):
                geom.size = model.geom_size[gid].copy()
        for joint, jid in zip(body.joints, _ids(model, model.jnt_bodyid, b)):
            joint.pos = model.jnt_pos[jid].copy()
            if joint.type in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
                joint.range = model.jnt_range[jid].copy()
        for site, sid in zip(body.sites, _ids(model, model.site_bodyid, b)):
            site.pos, site.quat = model.site_pos[sid].copy(), model.site_quat[sid].copy()
            site.alt.type = quat_type


def _ids(model, owner: np.ndarray, body_id: int) -> list[int]:
    # NOTE: MuJoCo keeps the spec's element order per body, so the k-th geom of a spec body is
    # the k-th model geom whose owner is that body.
    return [int(i) for i in np.flatnonzero(owner == body_id)]


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
