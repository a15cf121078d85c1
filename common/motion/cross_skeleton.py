"""Cross-skeleton retargeting: a BVH of another skeleton played on the DeepMimic humanoid.

UniCon 2020 (METHOD.md B) trains one executor on one character over every clip it can get; the
MASS clips (`Character1_*` skeleton) and CMU clips (31-joint cgspeed skeleton) were captured on
other skeletons, so they are brought onto the humanoid here (`retarget_bvh`).

Why local rotations cannot be copied. A BVH channel rotation, like a clip joint's rotation on
the humanoid (clip.py), means "turn away from *this skeleton's* rest pose", and the rest poses
differ: MASS and CMU stand in a T-pose (arms out sideways) while the humanoid's arms hang; CMU's
thighs splay about 20 degrees outward at rest; MASS's neck leans forward, its shin is longer than
its thigh. Copied as they are (`naive_clip`, the "raw" figures of `morphmimic motion check`),
a source standing with its arms down turns the humanoid's hanging arms a quarter turn (across
its chest), and the source's root height leaves the humanoid's shorter legs in the air (the
MASS walk floats 15 cm on average).

Rest-pose correction. Each humanoid body b is driven by one source joint s (`Segment`):
- G_s(t), the source joint's *global* rotation (its ancestors' local rotations and its own,
  multiplied down the chain), expressed in the humanoid's axes. At rest G_s = I and the source
  bone below s points along d_s, read off the rest offsets.
- C_b, the rest-pose correction: the rotation that takes the source bone direction at rest d_s
  onto the humanoid's bone direction at rest d_h (C_b d_s = d_h, e.g. a T-pose arm onto a
  hanging arm: 90 degrees about the forward axis). A bone direction leaves the twist about the
  bone free; a second pair of directions fixes it (forward stays forward for limbs; the hip
  line for the pelvis, the shoulder line for the chest; the toe direction for the feet).
- G_h(t) = G_s(t) C_b^-1, so G_h d_h = G_s d_s: at every frame the humanoid's bone points where
  the source's bone points. The source's T-pose comes out as the humanoid in a T-pose; a source
  pose whose bones lie along the humanoid's rest directions comes out as the humanoid's rest pose.
- Each humanoid joint's rotation is G_h(b) relative to the rotation its parent *reached*:
  ball joints take it whole, hinges (knees, elbows, axis (0, -1, 0)) its twist about their axis
  (clamped to the joint's range), and the next joint down is measured from the parent's rotation
  with that hinge angle, so a foot or forearm keeps its global orientation. Chains the humanoid
  merges (MASS Spine + Spine1 -> chest, the clavicles -> shoulders) need nothing special:
  only global rotations are used.

Root and floor. The humanoid's pelvis follows the midpoint of the source's hip joints, scaled by
the ratio of hip heights at rest (humanoid hip height above its soles / source hip height above
its lowest foot joint): strides and heights fit the shorter legs. Then the feet are put on the
floor frame by frame (`plant_feet`): contacts are found per foot by low foot speed and a height
near a *local* floor estimate (`floor_contacts`; a capture's floor may drift by centimetres over
a clip, the MASS walk's by 2.7 cm), the root moves vertically so the highest foot in contact sits
at z = 0 on every contact frame (each foot's contact height followed through its swing,
`FloorConfig.root_height`), and a leg pose solve lifts any other foot out of the floor
(root_height.py's root offsets and leg_solve.py's leg solve, reused).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from common.motion import quat
from common.motion.bvh import Bvh, parse_bvh
from common.motion.clip import Clip
from common.motion.errors import ClipError
from common.motion.import_bvh import BVH_TO_MUJOCO, CMU_SCALE_M, MASS_SCALE_M, TargetJoint, bvh_to_clip, hinge_twist
from common.motion.import_deepmimic import HUMANOID_JOINTS
from common.motion.qpos_map import QposMap
from common.motion.retarget import ContactPhases, RetargetConfig, retarget_qpos
from common.motion.root_height import foot_heights

# A direction at rest (`Segment`): `(from, to)` joint (source) or body (humanoid) names, the
# rest position of `to` minus that of `from`; a world axis of the Z-up frame (`AXES`); or a
# vector (x, y, z) of three numbers in the Z-up frame (a local axis of a source joint whose rest
# frame is rotated, e.g. Bandai Namco's thighs: their "left" is the file's +Y).
AXES = {"up": np.array([0.0, 0.0, 1.0]), "forward": np.array([1.0, 0.0, 0.0]), "left": np.array([0.0, 1.0, 0.0])}
TARGETS = ("humanoid",)
"""Characters a BVH can be retargeted onto (the segment maps below are the humanoid's bodies)."""


@dataclass(frozen=True)
class Segment:
    """One humanoid body driven by one source joint, with the directions that define its
    rest-pose correction: `source_dirs[0]` is matched exactly onto `target_dirs[0]`, the optional
    second pair fixes the twist about it (best fit)."""

    source: str
    source_dirs: tuple
    target_dirs: tuple


@dataclass(frozen=True)
class SourceSkeleton:
    """A BVH skeleton the humanoid can be driven from."""

    name: str
    scale_m: float
    """File units to metres."""
    hips: tuple[str, str]
    """(right, left) hip joints: the humanoid's pelvis follows their midpoint."""
    feet: tuple[str, ...]
    """Joints at the floor in the rest pose (ankles, toes): the source hip height is measured to the lowest."""
    segments: dict
    """{humanoid body: Segment}; the root body `root` must be there."""
    naive: dict
    """{humanoid joint: BVH joint(s)} whose local rotations a naive copy would use (`naive_clip`)."""
    stands_at_rest: bool = True
    """False when the rest pose (every rotation 0) does not stand (Bandai Namco's rotated rest
    frames lay the legs sideways): the source hip height is then measured in `standing_rest`."""

    def joints_named(self) -> set[str]:
        """Every BVH joint this map names."""
        out = set(self.hips) | set(self.feet)
        for seg in self.segments.values():
            out.add(seg.source)
            out.update(j for d in seg.source_dirs if _is_pair(d) for j in d)
        for v in self.naive.values():
            out.update((v,) if isinstance(v, str) else v)
        return out


def _segments(p: str, chest_top: str) -> dict[str, Segment]:
    """The humanoid's 13 segments driven from a skeleton with the common naming (MASS after its
    `Character1_` prefix and CMU agree): `{p}Hips`, `{p}Spine1`, `{p}Head`, `{p}RightUpLeg`,
    `{p}RightLeg`, `{p}RightFoot`, `{p}RightToeBase`, `{p}RightArm`, `{p}RightForeArm`,
    `{p}RightHand` and the Left ones; `chest_top` is the joint above the chest (the neck's base).

    Directions: limbs match their bone exactly and keep forward forward (both skeletons face
    forward at rest); the pelvis its hip line with up up; the chest its spine with the shoulder
    line; the feet keep up up (both rest poses stand on flat feet) and turn the toe direction
    forward; the head is upright and facing forward in both rest poses (no correction)."""
    out = {
        "root": Segment(p + "Hips", ((p + "RightUpLeg", p + "LeftUpLeg"), "up"), (("right_hip", "left_hip"), "up")),
        "chest": Segment(p + "Spine1", ((p + "Spine1", chest_top), (p + "RightArm", p + "LeftArm")),
                         (("chest", "neck"), ("right_shoulder", "left_shoulder"))),
        "neck": Segment(p + "Head", ("up", "forward"), ("up", "forward")),
    }
    for side in ("right", "left"):
        s, h = p + side.capitalize(), side + "_"
        for body, joint, child, body_child in (("hip", "UpLeg", "Leg", "knee"), ("knee", "Leg", "Foot", "ankle"),
                                               ("shoulder", "Arm", "ForeArm", "elbow"), ("elbow", "ForeArm", "Hand", "wrist")):
            out[h + body] = Segment(s + joint, ((s + joint, s + child), "forward"), ((h + body, h + body_child), "forward"))
        out[h + "ankle"] = Segment(s + "Foot", ("up", (s + "Foot", s + "ToeBase")), ("up", "forward"))
    return out


def _naive(p: str, chest: tuple[str, ...], neck: tuple[str, ...], hip_extra: str = "") -> dict:
    """{humanoid joint: BVH joint(s)} of a naive copy: chains the humanoid merges composed in
    order (CMU's `RHipJoint`/`LHipJoint` before the thighs when `hip_extra` is "HipJoint")."""
    out = {"root": p + "Hips", "chest": chest, "neck": neck}
    for side in ("right", "left"):
        s, h = p + side.capitalize(), side + "_"
        hip = (f"{side[0].upper()}{hip_extra}", s + "UpLeg") if hip_extra else s + "UpLeg"
        out.update({h + "hip": hip, h + "knee": s + "Leg", h + "ankle": s + "Foot",
                    h + "shoulder": (s + "Shoulder", s + "Arm"), h + "elbow": s + "ForeArm"})
    return out


def _feet(p: str) -> tuple[str, ...]:
    return (p + "RightToeBase", p + "LeftToeBase", p + "RightFoot", p + "LeftFoot")


BANDAI_FOOT_PITCH_DEG = 39.6
"""How far the Bandai Namco ankle -> toe bone points below the horizontal when the foot stands
flat: the median over the first frames of 62 standing takes (bow, raise, wave, call, respond)."""


def _bandai() -> SourceSkeleton:
    """The 22-joint Bandai Namco skeleton (`joint_Root` at the floor, `Hips`, `Spine`, `Chest`,
    `Neck`, `Head`, `{Shoulder,UpperArm,LowerArm,Hand}_{L,R}`, `{UpperLeg,LowerLeg,Foot,Toes}_{L,R}`,
    30 fps, cm, Y up, +Z forward). Its joints' rest frames are rotated: with every rotation 0 the
    spine and legs lie along the file's X (the all-zero pose does not stand), so the twist of a
    bone cannot be read off the world axes as for MASS and CMU. Bone directions come from the
    offsets; the second direction of each segment is the joint's local axis that is anatomical in
    every take (read off standing frames): the spine joints' local +X is up and +Z left, the hips'
    +X up and -Y left (the hip line from the offsets), the thighs' and shins' +Y left (the knee
    axis), the left arm's +Z and the right arm's -Z forward, and the feet's "up" lies in their
    local X-Z plane `BANDAI_FOOT_PITCH_DEG` from the toe bone (file axes -> Z-up via BVH_TO_MUJOCO)."""
    def ax(x, y, z):  # a file-axes vector in the Z-up frame
        return tuple(BVH_TO_MUJOCO @ np.array([x, y, z], dtype=float))

    pitch = np.radians(BANDAI_FOOT_PITCH_DEG)
    segs = {
        "root": Segment("Hips", (("UpperLeg_R", "UpperLeg_L"), ("Hips", "Spine")), (("right_hip", "left_hip"), "up")),
        "chest": Segment("Chest", (("Chest", "Neck"), ("Shoulder_R", "Shoulder_L")),
                         (("chest", "neck"), ("right_shoulder", "left_shoulder"))),
        "neck": Segment("Head", (ax(1, 0, 0), ax(0, 0, 1)), ("up", "left")),
    }
    naive = {"root": "Hips", "chest": ("Spine", "Chest"), "neck": ("Neck", "Head")}
    for side, s, sign in (("right", "_R", -1.0), ("left", "_L", 1.0)):
        h = side + "_"
        for body, joint, child, body_child, second, target in (
                ("hip", "UpperLeg", "LowerLeg", "knee", ax(0, 1, 0), "left"),
                ("knee", "LowerLeg", "Foot", "ankle", ax(0, 1, 0), "left"),
                ("shoulder", "UpperArm", "LowerArm", "elbow", ax(0, 0, sign), "forward"),
                ("elbow", "LowerArm", "Hand", "wrist", ax(0, 0, sign), "forward")):
            segs[h + body] = Segment(joint + s, ((joint + s, child + s), second), ((h + body, h + body_child), target))
        foot_up = ax(-sign * np.sin(pitch), 0.0, sign * np.cos(pitch))
        segs[h + "ankle"] = Segment("Foot" + s, (foot_up, ("Foot" + s, "Toes" + s)), ("up", "forward"))
        naive.update({h + "hip": "UpperLeg" + s, h + "knee": "LowerLeg" + s, h + "ankle": "Foot" + s,
                      h + "shoulder": ("Shoulder" + s, "UpperArm" + s), h + "elbow": "LowerArm" + s})
    return SourceSkeleton("bandai", BANDAI_SCALE_M, ("UpperLeg_R", "UpperLeg_L"), ("Toes_R", "Toes_L", "Foot_R", "Foot_L"),
                          segs, naive, stands_at_rest=False)


BANDAI_SCALE_M = 0.01
"""Bandai Namco BVH units (cm) to metres."""
_M = "Character1_"
SOURCE_SKELETONS: dict[str, SourceSkeleton] = {s.name: s for s in (
    SourceSkeleton("mass", MASS_SCALE_M, (_M + "RightUpLeg", _M + "LeftUpLeg"), _feet(_M), _segments(_M, _M + "Neck"),
                   _naive(_M, (_M + "Spine", _M + "Spine1"), (_M + "Neck", _M + "Head"))),
    SourceSkeleton("cmu", CMU_SCALE_M, ("RightUpLeg", "LeftUpLeg"), _feet(""), _segments("", "Neck1"),
                   _naive("", ("LowerBack", "Spine", "Spine1"), ("Neck", "Neck1", "Head"), hip_extra="HipJoint")),
    _bandai(),
)}
"""The BVH skeletons the humanoid can be driven from, by name (manifest field `retarget_from`)."""


def _is_pair(spec) -> bool:
    """True for a `(from, to)` pair of names (not an axis name, not a vector)."""
    return not isinstance(spec, str) and len(spec) == 2 and all(isinstance(x, str) for x in spec)


def source_skeleton(skeleton: str | SourceSkeleton) -> SourceSkeleton:
    """A skeleton by name ('mass', 'cmu', 'bandai') or as given; ClipError naming an unknown name."""
    if isinstance(skeleton, SourceSkeleton):
        return skeleton
    if skeleton not in SOURCE_SKELETONS:
        raise ClipError(f"unknown source skeleton {skeleton!r}; choose one of {', '.join(map(repr, SOURCE_SKELETONS))}")
    return SOURCE_SKELETONS[skeleton]


@dataclass(frozen=True)
class _Target:
    """What the mapping needs of the target character at rest (body frames parallel to the world)."""

    model: object
    feet: tuple[str, ...]
    body_pos: dict
    """{body name: rest world position (3,)}."""
    parent: dict
    """{body name: parent body name} for jointed bodies below the root."""
    order: tuple[str, ...]
    """Jointed bodies, parents first."""
    hinges: dict
    """{hinge joint name: (axis (3,), lo, hi)}."""
    hip_height_m: float
    """Root height above the lowest sole point at rest."""


@functools.lru_cache(maxsize=None)
def _target(character: str) -> _Target:
    if character not in TARGETS:
        raise ClipError(f"cannot retarget a BVH onto character {character!r}; targets: {', '.join(map(repr, TARGETS))}")

    # lazy: start-up time of train --help, which loads common.motion (common.characters adds scipy.optimize)
    from common.characters import load_character

    ch = load_character(character)
    m = ch.model
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    if np.abs(np.abs(d.xquat[1:, 0]) - 1.0).max() > 1e-9:
        raise ClipError(f"the {character!r} model's body frames are not parallel to the world at rest")
    names = [m.body(b).name for b in range(m.nbody)]
    body_pos = {names[b]: d.xpos[b].copy() for b in range(1, m.nbody)}
    parent, order, hinges = {}, [], {}
    for j in range(1, m.njnt):
        b = int(m.jnt_bodyid[j])
        parent[names[b]] = names[int(m.body_parentid[b])]
        order.append(names[b])
        if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE:
            lo, hi = (m.jnt_range[j] if m.jnt_limited[j] else (-np.inf, np.inf))
            hinges[m.joint(j).name] = (m.jnt_axis[j] / np.linalg.norm(m.jnt_axis[j]), float(lo), float(hi))
    feet = tuple(ch.foot_geoms)
    h, _ = foot_heights(m, m.qpos0[None], feet)
    return _Target(m, feet, body_pos, parent, tuple(order), hinges, float(m.qpos0[2] - h.min()))


@dataclass(frozen=True)
class SourcePose:
    """A BVH's forward kinematics in the Z-up humanoid axes, metres."""

    names: tuple[str, ...]
    rotations: dict
    """{joint: Rotation (N,)} global rotations."""
    positions: np.ndarray
    """(N, J, 3) joint positions."""
    rest: np.ndarray
    """(J, 3) joint positions at rest (every rotation the identity, root at its offset)."""

    def at_rest(self, joint: str) -> np.ndarray:
        return self.rest[self.names.index(joint)]


def source_pose(bvh: Bvh, scale_m: float, axes: np.ndarray = BVH_TO_MUJOCO) -> SourcePose:
    """Global joint rotations and positions of every frame (BVH rest frames carry no rotation, so
    a global rotation is the product of the local ones from the root down)."""
    m = Rotation.from_matrix(axes)
    n, names = bvh.num_frames, bvh.joint_names
    offsets = bvh.offsets * scale_m @ axes.T
    rots: dict[str, Rotation] = {}
    pos = np.zeros((n, len(names), 3))
    rest = np.zeros((len(names), 3))
    for j, (name, p) in enumerate(zip(names, bvh.parents)):
        local = m * bvh.local_rotations(name) * m.inv()
        if p < 0:
            rots[name] = local
            pos[:, j] = bvh.root_positions() * scale_m @ axes.T
            rest[j] = offsets[j]
        else:
            parent = rots[names[p]]
            rots[name] = parent * local
            step = bvh.local_translations(name) * scale_m @ axes.T if bvh.has_positions(name) else offsets[j]
            pos[:, j] = pos[:, p] + parent.apply(step)
            rest[j] = rest[p] + offsets[j]
    return SourcePose(names, rots, pos, rest)


def _direction(spec, position) -> np.ndarray:
    if isinstance(spec, str):
        if spec not in AXES:
            raise ClipError(f"direction {spec!r} is not a pair of names nor one of {', '.join(AXES)}")
        return AXES[spec]
    if not _is_pair(spec):
        v = np.asarray(spec, dtype=float)
        if v.shape != (3,) or not np.linalg.norm(v) > 1e-9:
            raise ClipError(f"direction {spec!r} is not a pair of names, an axis name nor a nonzero 3-vector")
        return v / np.linalg.norm(v)
    a, b = spec
    v = position(b) - position(a)
    norm = np.linalg.norm(v)
    if norm < 1e-9:
        raise ClipError(f"direction {a!r} -> {b!r} has zero length at rest")
    return v / norm


def rest_corrections(skeleton: SourceSkeleton, pose: SourcePose, character: str = "humanoid") -> dict[str, Rotation]:
    """{humanoid body: C_b}, the rotation taking each source bone direction at rest onto the
    humanoid's bone direction at rest (C_b d_s = d_h exactly for the first direction pair; the
    second, if any, is matched as well as that allows: it fixes the twist about the bone)."""
    target = _target(character)
    out = {}
    for body, seg in skeleton.segments.items():
        src = np.stack([_direction(d, pose.at_rest) for d in seg.source_dirs])
        dst = np.stack([_direction(d, target.body_pos.__getitem__) for d in seg.target_dirs])
        weights = [np.inf] + [1.0] * (len(src) - 1) if len(src) > 1 else None
        out[body] = Rotation.align_vectors(dst, src, weights=weights)[0]
    return out


def standing_rest(bvh: Bvh, pose: SourcePose, skeleton: SourceSkeleton, corr: dict[str, Rotation]) -> np.ndarray:
    """(J, 3) joint positions of the source standing as the humanoid stands at rest: each mapped
    joint turned by its rest correction C_b (its bones onto the humanoid's rest directions: legs
    straight down, feet flat), an unmapped joint (spine, toes, hands) turned with its parent;
    lengths from the rest offsets. For a skeleton whose all-zero pose does not stand
    (`stands_at_rest` False), where the hip height above the feet is measured."""
    turn = {seg.source: corr[body] for body, seg in skeleton.segments.items()}
    glob: dict[str, Rotation] = {}
    out = np.zeros_like(pose.rest)
    for j, (name, p) in enumerate(zip(pose.names, bvh.parents)):
        parent = glob[pose.names[p]] if p >= 0 else Rotation.identity()
        glob[name] = turn.get(name, parent)
        out[j] = pose.rest[j] if p < 0 else out[p] + parent.apply(pose.rest[j] - pose.rest[p])
    return out


def _validate(skeleton: SourceSkeleton, bvh: Bvh, target: _Target) -> None:
    missing = sorted(skeleton.joints_named() - set(bvh.joint_names))
    if missing:
        raise ClipError(f"the {skeleton.name!r} skeleton map names BVH joint(s) {missing} that the file lacks; "
                        f"its joints: {', '.join(bvh.joint_names)}", path=bvh.path, joint=missing[0])
    bodies = set(target.body_pos)
    jointed = set(target.order) | {"root"}
    named = set(skeleton.segments) | set(skeleton.naive)
    for seg in skeleton.segments.values():
        named.update(b for d in seg.target_dirs if _is_pair(d) for b in d)
    unknown = sorted(n for n in named if n not in bodies or (n in skeleton.segments and n not in jointed))
    if unknown:
        raise ClipError(f"the {skeleton.name!r} skeleton map names humanoid bodies {unknown} that are not jointed bodies "
                        f"of the character; its joints: {', '.join(['root', *target.order])}", path=bvh.path, joint=unknown[0])
    if "root" not in skeleton.segments:
        raise ClipError(f"the {skeleton.name!r} skeleton map must drive the root body 'root'", path=bvh.path)


BEND_RAMP_RAD = (np.radians(5.0), np.radians(20.0))
"""A limb bent less than the first angle gets no bend-plane aim, more than the second the whole."""
TWIST_RAMP_RAD = (np.radians(60.0), np.radians(120.0))
"""A needed twist beyond the first angle is faded out, to none beyond the second (a source bend
the hinge cannot make, e.g. a hyperextended elbow, would need a half turn that flips)."""


def _ramp(x: np.ndarray, a: float, b: float) -> np.ndarray:
    return np.clip((x - a) / (b - a), 0.0, 1.0)


def aim_bend_plane(want_b: Rotation, want_c: Rotation, d_b: np.ndarray, d_c: np.ndarray, axis: np.ndarray,
                   lo: float, hi: float) -> Rotation:
    """The global rotations (N,) of a ball-jointed body b (hip, shoulder) turned about its own bone
    so that its hinge child c (knee, elbow) can bend onto the child's wanted bone direction.

    A hinge keeps only the twist of the child's rotation about its axis; where the source's
    knee or elbow bends in another plane than the one the humanoid's hinge axis allows (a
    different twist convention of the source's upper arm, swing in a source's knee), the
    child's bone would miss its direction (without the turn: up to 41 degrees on the MASS
    pirouette's elbows, 22 on average on the CMU clip's). Turning b about its bone by the angle
    that puts the hinge axis along +-(u x w) (u: b's bone, w: the child's bone's component
    across u; the sign from the hinge's one-sided range) keeps b's bone direction and lets the
    hinge reach the child's. Faded in over a bend of `BEND_RAMP_RAD` (a straight limb has no bend
    plane) and out over a needed twist of `TWIST_RAMP_RAD`. Assumes the child's bone continues
    b's at rest (d_c = d_b: the humanoid's straight limbs); otherwise and for two-sided hinges
    `want_b` is returned unchanged."""
    side = 1.0 if lo >= 0.0 else -1.0 if hi <= 0.0 else 0.0
    if side == 0.0 or np.dot(d_b, d_c) < 1.0 - 1e-6:
        return want_b
    u, v = want_b.apply(d_b), want_c.apply(d_c)
    u, v = np.atleast_2d(u), np.atleast_2d(v)
    a = np.atleast_2d(want_b.apply(axis))
    a = a - np.sum(a * u, axis=1, keepdims=True) * u
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    cos_beta = np.clip(np.sum(u * v, axis=1), -1.0, 1.0)
    w = v - cos_beta[:, None] * u
    w /= np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-12)
    goal = side * np.cross(u, w)
    phi = np.arctan2(np.sum(np.cross(a, goal) * u, axis=1), np.sum(a * goal, axis=1))
    weight = _ramp(np.arccos(cos_beta), *BEND_RAMP_RAD) * (1.0 - _ramp(np.abs(phi), *TWIST_RAMP_RAD))
    return Rotation.from_rotvec((weight * phi)[:, None] * u) * want_b


def map_pose(bvh: Bvh, skeleton: str | SourceSkeleton = "mass", character: str = "humanoid") -> Clip:
    """The BVH's motion on the humanoid by global rotations with rest-pose correction (module
    docstring), root scaled by the hip-height ratio; the feet are not yet planted (`plant_feet`).

    UniCon 2020 (METHOD.md B): one executor on one character imitates clips of every skeleton;
    this is the mapping that brings a MASS (`Character1_*`) or CMU (31-joint) BVH onto the
    DeepMimic humanoid: per mapped segment, G_h = G_s C_b^-1 with C_b the rest-pose correction
    (`rest_corrections`), each humanoid joint relative to its parent's reached rotation, hinges
    (knees, elbows) the twist about their axis.
    Raises ClipError on an unknown skeleton or character, or a map naming a joint the file or
    the character lacks.
    """
    skel = source_skeleton(skeleton)
    target = _target(character)
    _validate(skel, bvh, target)
    pose = source_pose(bvh, skel.scale_m)
    corr = rest_corrections(skel, pose, character)
    n = bvh.num_frames
    want = {body: pose.rotations[seg.source] * corr[body].inv() for body, seg in skel.segments.items()}
    for child, (axis, lo, hi) in target.hinges.items():
        body = target.parent[child]
        if child in skel.segments and body in skel.segments and body not in target.hinges:
            d_b = _direction(skel.segments[body].target_dirs[0], target.body_pos.__getitem__)
            d_c = _direction(skel.segments[child].target_dirs[0], target.body_pos.__getitem__)
            want[body] = aim_bend_plane(want[body], want[child], d_b, d_c, axis, lo, hi)
    reached: dict[str, Rotation] = {"root": want["root"]}
    locals_: dict[str, np.ndarray] = {}
    for body in target.order:
        parent = reached[target.parent[body]]
        local = parent.inv() * want.get(body, parent)
        if body in target.hinges:
            axis, lo, hi = target.hinges[body]
            angle = np.clip(hinge_twist(quat.wxyz(local), axis), lo, hi)
            locals_[body] = angle[:, None]
            reached[body] = parent * Rotation.from_rotvec(angle[:, None] * axis)
        else:
            locals_[body] = quat.continuous(quat.wxyz(local))
            reached[body] = want.get(body, parent)
    # Root: the source hip joints' midpoint, scaled by the ratio of hip heights at rest.
    hips = [pose.names.index(h) for h in skel.hips]
    rest = pose.rest if skel.stands_at_rest else standing_rest(bvh, pose, skel, corr)
    feet_rest = min(rest[pose.names.index(f), 2] for f in skel.feet)
    src_hip_height = float(rest[hips, 2].mean() - feet_rest)
    if src_hip_height <= 0:
        raise ClipError(f"source hip height at rest is {src_hip_height:.3f} m; the hips must be above the feet", path=bvh.path)
    ratio = target.hip_height_m / src_hip_height
    mid = pose.positions[:, hips].mean(axis=1)
    root_pos = ratio * mid
    names = tuple(name for name, _ in HUMANOID_JOINTS)
    types = tuple(kind for _, kind in HUMANOID_JOINTS)
    axes = np.array([target.hinges[nm][0] if kind == "hinge" else np.zeros(3) for nm, kind in HUMANOID_JOINTS])
    return Clip(
        name=Path(bvh.path).stem, fps=1.0 / bvh.frame_time_s, root_pos=root_pos, root_quat=quat.continuous(quat.wxyz(reached["root"])),
        joint_names=names, joint_types=types, joint_qpos=np.concatenate([locals_[nm] for nm in names], axis=1),
        hinge_axes=axes, character=character, source=f"bvh:{Path(bvh.path).name}",
        extra={"native_fps": 1.0 / bvh.frame_time_s, "scale_m": skel.scale_m, "retarget_from": skel.name,
               "hip_height_ratio": ratio, "frames": n},
    )


@dataclass(frozen=True)
class FloorConfig:
    """How contacts and the local floor are found on a retargeted clip (m, m/s, s)."""

    window_s: float = 0.5
    """Half-width of the time window over which the local floor is fitted."""
    envelope_m: float = 0.02
    """Points further than this above the fitted floor are dropped from the fit (it is a lower envelope)."""
    contact_height_m: float = 0.04
    """A foot is in contact when its lowest point is this close to the local floor..."""
    contact_speed_m_s: float = 0.8
    """...and its body moves horizontally slower than this."""
    max_drift_m_s: float = 0.2
    """The local floor's slope is bounded by this rise or fall per second (`local_floor`)."""
    root_height: str = "foot_tracks"
    """Root-height rule of the planting (`root_height.root_offsets`): "foot_tracks" follows each
    foot's in-contact height through its swing, so the root does not jump when a foot joins the
    contact set at another height (measured on the MASS balance: largest root step between
    frames 4 mm, against 40 mm with "contact_set"; the feet as planted either way)."""


MIN_SLOW_S = 0.1
"""`local_floor` fits a window holding at least this much time of slow frames (or all there are)."""


def local_floor(low: np.ndarray, slow: np.ndarray, fps: float, cfg: FloorConfig = FloorConfig()) -> np.ndarray:
    """Floor height (T,) m at each frame, from the lowest foot's height `low` (T,) on frames where
    a foot is `slow` (T,): a line fitted to those points within +-`window_s` (widened until it
    holds `MIN_SLOW_S` of slow frames; all frames if the clip has none), as a lower envelope (points more than
    `envelope_m` above the line are dropped and it is fitted again), its slope bounded by
    `max_drift_m_s` so that a cluster of points at one end of the window cannot tilt it far,
    evaluated at the frame. A drifting floor (a capture's floor rising by 8 cm over a clip) is
    followed; one height for the whole clip is never assumed."""
    t = np.arange(len(low)) / fps
    if not slow.any():
        slow = np.ones(len(low), dtype=bool)
    need = min(int(slow.sum()), max(3, int(round(MIN_SLOW_S * fps))))
    out = np.empty(len(low))
    for k in range(len(low)):
        half = cfg.window_s
        sel = (np.abs(t - t[k]) <= half) & slow
        while sel.sum() < need and half < t[-1] - t[0] + cfg.window_s:
            half *= 2.0
            sel = (np.abs(t - t[k]) <= half) & slow
        x, y = t[sel] - t[k], low[sel]
        level = float(np.mean(y))
        for _ in range(4):
            slope = 0.0
            if len(x) >= 3 and np.ptp(x) > 2.0 / fps:
                slope = float(np.clip(np.polyfit(x, y, 1)[0], -cfg.max_drift_m_s, cfg.max_drift_m_s))
            level = float(np.mean(y - slope * x))
            keep = y - (level + slope * x) <= cfg.envelope_m
            if keep.all() or keep.sum() < 3:
                break
            x, y = x[keep], y[keep]
        out[k] = level
    return out


def floor_contacts(h: np.ndarray, foot_pos: np.ndarray, fps: float, cfg: FloorConfig = FloorConfig()) -> tuple[np.ndarray, np.ndarray]:
    """(flags (T, F) bool, floor (T,) m): which foot touches the floor in which frame, from each
    foot's lowest-point height `h` (T, F) and its body position `foot_pos` (T, F, 3).

    Per foot: in contact when slow (horizontal speed under `contact_speed_m_s`) and its lowest
    point within `contact_height_m` of the local floor (`local_floor`, fitted to the lowest slow
    foot of the frames around), not of one floor height for the whole clip."""
    speed = np.linalg.norm(np.gradient(foot_pos[:, :, :2], axis=0), axis=-1) * fps
    slow = speed < cfg.contact_speed_m_s
    low = np.where(slow, h, np.inf).min(axis=1)
    any_slow = np.isfinite(low)
    low = np.where(any_slow, low, h.min(axis=1))
    floor = local_floor(low, any_slow, fps, cfg)
    flags = slow & (h - floor[:, None] < cfg.contact_height_m)
    return flags, floor


def clip_from_qpos(clip: Clip, model, qpos: np.ndarray) -> Clip:
    """`clip` with its frames replaced by qpos frames (T, nq) of `model`, whose body frames are
    parallel to the world at rest (the humanoid): the clip's joint rotations are then the
    model's ball quaternions and hinge angles, read by joint name."""
    parts = []
    for name, kind in zip(clip.joint_names, clip.joint_types):
        adr = int(model.jnt_qposadr[model.joint(name).id])
        parts.append(quat.continuous(qpos[:, adr:adr + 4]) if kind == "ball" else qpos[:, adr:adr + 1])
    return clip.with_(root_pos=qpos[:, 0:3].copy(), root_quat=quat.continuous(qpos[:, 3:7]), joint_qpos=np.concatenate(parts, axis=1))


def plant_feet(clip: Clip, character: str = "humanoid", cfg: FloorConfig = FloorConfig()) -> Clip:
    """The clip with its stance feet on the floor (z = 0) on every contact frame: contacts per
    foot against the local floor (`floor_contacts`), then retarget.py's per-frame root offset
    (the highest contact foot at 0, interpolated across flight) and leg pose solve (any foot
    below the floor lifted onto it). `extra["contact_frac"]` records each foot's contact share."""
    target = _target(character)
    model, feet = target.model, target.feet
    qpos = QposMap(clip, model).to_qpos(clip.root_pos, clip.root_quat, clip.joint_qpos)
    h, pos = foot_heights(model, qpos, feet)
    flags, _ = floor_contacts(h, pos, clip.fps, cfg)
    rcfg = RetargetConfig(contact_height_m=cfg.contact_height_m, contact_speed_m_s=cfg.contact_speed_m_s, root_height=cfg.root_height)
    qpos = retarget_qpos(clip, model, feet, 1.0, ContactPhases(feet, flags, 0.0), rcfg)
    out = clip_from_qpos(clip, model, qpos)
    return out.with_(extra={**clip.extra, "contact_frac": [round(float(f), 3) for f in flags.mean(axis=0)]})


def retarget_bvh(source: str | Path | Bvh, *, skeleton: str | SourceSkeleton = "mass", character: str = "humanoid",
                 name: str | None = None, label: str = "root", license: str = "", loop: bool = False,
                 plant: bool = True, cfg: FloorConfig = FloorConfig()) -> Clip:
    """A BVH of another skeleton as a canonical clip of `character` (the DeepMimic humanoid).

    UniCon 2020 (METHOD.md B): one executor on one character imitates every clip; clips of other
    skeletons are retargeted onto it: global rotations with a per-segment rest-pose correction
    (`map_pose`; the module docstring explains it), root scaled by the hip-height ratio, then
    the feet planted on a floor that may drift (`plant_feet`).

    Args:
        source: a `.bvh` path or a parsed `Bvh`.
        skeleton: the source skeleton map, 'mass' (`Character1_*`) or 'cmu' (31 joints), or a
            `SourceSkeleton`.
        plant: put the feet on the floor (default); False leaves the mapped pose as it is.
    The clip's `extra` records `retarget_from` (the skeleton's name) and `source_path` (the
    BVH's path: `morphmimic motion check` rebuilds the naive copy from it for its "raw" figures).
    Raises:
        ClipError naming the value on an unknown skeleton or character, or a map naming a joint
        the file or the character lacks.
    """
    skel = source_skeleton(skeleton)
    _target(character)
    bvh = source if isinstance(source, Bvh) else parse_bvh(source)
    clip = map_pose(bvh, skel, character)
    if plant:
        clip = plant_feet(clip, character, cfg)
    return clip.with_(name=name or Path(bvh.path).stem, label=label, license=license, loop=loop,
                      extra={**clip.extra, "source_path": str(bvh.path)})


def naive_clip(source: str | Path | Bvh, *, skeleton: str | SourceSkeleton = "mass", character: str = "humanoid") -> Clip:
    """The BVH copied naively onto the humanoid: each joint's local rotations (chains composed),
    no rest-pose correction, the root as recorded. What `motion check` shows as "raw" for a
    cross-skeleton clip: the figures retargeting has to fix."""
    skel = source_skeleton(skeleton)
    target = _target(character)
    bvh = source if isinstance(source, Bvh) else parse_bvh(source)
    _validate(skel, bvh, target)
    joints = tuple(TargetJoint(nm, kind, target.hinges[nm][0] if kind == "hinge" else np.zeros(3)) for nm, kind in HUMANOID_JOINTS)
    return bvh_to_clip(bvh, root="root", joints=joints, name_map=dict(skel.naive), scale_m=skel.scale_m,
                       character=character, name=Path(bvh.path).stem)


def guess_skeleton(path: str | Path) -> str:
    """'mass' when the file's root joint is MASS's `Character1_Hips`, 'bandai' when it is Bandai
    Namco's `joint_Root`, else 'cmu'."""
    head = Path(path).read_text(errors="replace")[:2000]
    return "mass" if "Character1_Hips" in head else "bandai" if "ROOT joint_Root" in head else "cmu"


__all__ = [
    "FloorConfig", "SOURCE_SKELETONS", "Segment", "SourceSkeleton", "TARGETS", "aim_bend_plane", "clip_from_qpos", "floor_contacts",
    "guess_skeleton", "local_floor", "map_pose", "naive_clip", "plant_feet", "rest_corrections", "retarget_bvh",
    "source_pose", "source_skeleton",
]
