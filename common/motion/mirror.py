"""A clip's left-right mirror image: the same motion done with the other hand and foot, turning the
other way. Mirroring is the one augmentation that makes new, physically valid motions from
captured ones without a model of style: a symmetric body can do a mirrored motion exactly as
well as the original. The executor (UniCon; METHOD.md B) trains on 16 clips and its held-out
split did not move with more steps (docs/executor.md), so `--task.executor.mirror` doubles the
library it learns from; a mirrored clip keeps its source's label and its side of the split.

    mirror_clip(clip)                    # a Clip named `<name>~mirror`
    mirrored_id("humanoid3d_kick")       # "humanoid3d_kick~mirror"; source_id() undoes it

The reflection is across the vertical plane through the world origin whose normal is the
character's lateral axis at rest (world y for the humanoid and the biped: their left bodies sit
at +y). With M = diag(1, -1, 1) for normal y, a position p becomes M p and a rotation R becomes
M R M: a quaternion (w, x, y, z) becomes (w, -x, y, -z). Clip rotations are expressed in
world-aligned rest frames (`clip.py`), so the same rule holds for the root and for every joint,
and joint data move to the mirror partner (left_hip <-> right_hip, FemurL <-> FemurR). A hinge
turning by theta about axis a becomes a turn by theta about -M a (an axis is a pseudovector);
its partner's axis b is that or its opposite, so the partner's angle is theta (b . -M a).
`MotionLibrary.clip` builds `<id>~mirror` on demand and first checks that the character's rest
pose is symmetric under the reflection (`check_symmetric`).
"""

from __future__ import annotations

import re

import numpy as np

from common.motion.clip import Clip
from common.motion.errors import ClipError

MIRROR_SUFFIX = "~mirror"
"""Appended to a clip id (or name) to name its mirror image."""
_SIDES = (  # where a name says its side: left_hip, LeftUpLeg, FemurL, hip_l
    re.compile(r"^(left|right)(?=[_A-Z]|$)", re.I),
    re.compile(r"(?<=_)(left|right|l|r)$", re.I),
    re.compile(r"(?<=[a-z])(L|R)$"),
)


def _other_side(side: str) -> str:
    """right for left, R for L, Left for Right ...: the word for the other side, in the same case."""
    other = {"left": "right", "right": "left", "l": "r", "r": "l"}[side.lower()]
    if side.isupper():
        return other.upper()
    return other.capitalize() if side[0].isupper() else other


def mirrored_id(clip_id: str) -> str:
    """The id of `clip_id`'s mirror image (mirroring twice gives the clip back)."""
    return source_id(clip_id) if is_mirrored(clip_id) else clip_id + MIRROR_SUFFIX


def is_mirrored(clip_id: str) -> bool:
    return clip_id.endswith(MIRROR_SUFFIX)


def source_id(clip_id: str) -> str:
    """The clip a mirrored id was made from (`clip_id` itself when it is not mirrored)."""
    return clip_id[: -len(MIRROR_SUFFIX)] if is_mirrored(clip_id) else clip_id


def partner_name(name: str) -> str:
    """The mirror partner of a joint or body name: its left/right counterpart, or the name itself
    for a joint on the midline (chest, Spine)."""
    for pattern in _SIDES:
        m = pattern.search(name)
        if m:
            return name[: m.start(1)] + _other_side(m.group(1)) + name[m.end(1):]
    return name


def partners(names: tuple[str, ...] | list[str]) -> list[int]:
    """For each name, the index of its partner in `names`; ClipError when a sided name's partner
    is missing (a one-armed skeleton cannot be mirrored)."""
    index = {n: i for i, n in enumerate(names)}
    out = []
    for n in names:
        p = partner_name(n)
        if p not in index:
            raise ClipError(f"joint {n!r} has no mirror partner {p!r} in this skeleton; only left-right symmetric "
                            "skeletons can be mirrored")
        out.append(index[p])
    return out


def reflect_quat(q: np.ndarray, axis: int = 1) -> np.ndarray:
    """M R M for the reflection M across the plane whose normal is world axis `axis` (0: x, 1: y),
    on (..., 4) quaternions (w, x, y, z): the components of the other two axes change sign."""
    out = np.array(q, dtype=float, copy=True)
    for k in (0, 1, 2):
        if k != axis:
            out[..., 1 + k] *= -1.0
    return out


def mirror_clip(clip: Clip, axis: int = 1) -> Clip:
    """`clip` reflected across the vertical plane with normal world axis `axis` (module
    docstring), joints swapped with their partners; named `<name>~mirror`, same fps, label,
    loop flag, character, license. ClipError when a joint has no partner or a hinge's partner
    axis is not the mirror of its own."""
    if axis not in (0, 1):
        raise ClipError(f"mirror axis {axis} must be 0 (x) or 1 (y): the plane is vertical", path=clip.name)
    flip = np.ones(3)
    flip[axis] = -1.0
    pairs = partners(clip.joint_names)
    slices = clip.joint_slices()
    joint_qpos = np.empty_like(clip.joint_qpos)
    for j, p in enumerate(pairs):
        if clip.joint_types[j] != clip.joint_types[p]:
            raise ClipError(f"joint {clip.joint_names[j]!r} is a {clip.joint_types[j]} joint but its partner "
                            f"{clip.joint_names[p]!r} is a {clip.joint_types[p]} joint", path=clip.name)
        src = clip.joint_qpos[:, slices[j]]
        if clip.joint_types[j] == "ball":
            joint_qpos[:, slices[p]] = reflect_quat(src, axis)
        else:
            turned = -flip * clip.hinge_axes[j]  # the mirrored rotation's axis, -M a
            sign = float(np.dot(clip.hinge_axes[p], turned))
            if abs(abs(sign) - 1.0) > 1e-6:
                raise ClipError(f"hinge {clip.joint_names[j]!r} turns about {clip.hinge_axes[j].tolist()}, its partner "
                                f"{clip.joint_names[p]!r} about {clip.hinge_axes[p].tolist()}: not mirror images",
                                path=clip.name)
            joint_qpos[:, slices[p]] = sign * src
    return clip.with_(
        name=mirrored_id(clip.name), root_pos=clip.root_pos * flip, root_quat=reflect_quat(clip.root_quat, axis),
        joint_qpos=joint_qpos, source=f"mirror of {clip.source or clip.name}",
        extra={**clip.extra, "mirror_of": clip.name, "mirror_axis": "xy"[axis]},
    )


def check_symmetric(model, data, axis: int = 1, tol_m: float = 0.01) -> None:
    """ClipError unless the model's bodies, at the pose in `data` (run `mj_forward` first; the
    rest pose for a clip), sit where the reflection puts their partners to within `tol_m`: the
    mirror of a motion is only that motion's mirror on a symmetric body."""
    names = [model.body(i).name for i in range(1, model.nbody)]
    index = {n: i + 1 for i, n in enumerate(names)}
    flip = np.ones(3)
    flip[axis] = -1.0
    worst, where = 0.0, ""
    for n in names:
        p = partner_name(n)
        if p not in index:
            raise ClipError(f"body {n!r} has no mirror partner {p!r}; the character is not left-right symmetric")
        gap = float(np.linalg.norm(data.xpos[index[n]] * flip - data.xpos[index[p]]))
        if gap > worst:
            worst, where = gap, f"{n} / {p}"
    if worst > tol_m:
        raise ClipError(f"the character is not left-right symmetric across the plane normal to world "
                        f"{'xy'[axis]}: {where} are {worst * 1000:.0f} mm from mirror images (allowed {tol_m * 1000:.0f})")
