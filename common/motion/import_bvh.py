"""Import BVH motion onto a character's joints through a name map (MASS clips, CMU clips).

A name map says, for each joint of the target character, which BVH joint(s) drive it:
`{"FemurR": "Character1_RightUpLeg", "Torso": ("Spine", "Spine1"), ...}`. Several BVH joints
are composed in order (their local rotations multiply), which is how a 31-joint CMU skeleton
drives the 19-segment biped. Both the BVH rest frames and the targets' rest frames carry no
rotation, so local rotations carry over directly (the MASS convention, Lee et al. 2019);
ball joints take the whole rotation, hinge joints its twist about their axis.
Axes: MASS and CMU are Y up, facing +Z, left on +X; the biped (characters/presets/biped.py)
is Z up, facing +X, left on +Y: vectors map by `BVH_TO_MUJOCO`, (x, y, z) -> (z, x, y), and
rotations by conjugation with it. Lengths are multiplied by `scale_m` (MASS: cm -> 0.01,
CMU: 0.056444).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from common.motion import quat
from common.motion.bvh import Bvh, parse_bvh
from common.motion.clip import Clip
from common.motion.errors import ClipError
from common.motion.kinematics import resample_by_time

DATA_DIR = Path(__file__).resolve().parent.parent / "data"
MASS_SKELETON = DATA_DIR / "models" / "mass_human" / "human.xml"
MASS_SCALE_M = 0.01
CMU_SCALE_M = 0.056444
BVH_TO_MUJOCO = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
# The 4 toe bodies are not part of the paper's 19-segment full biped.
_DROPPED_BODIES = ("FootThumbR", "FootPinkyR", "FootThumbL", "FootPinkyL")


@dataclass(frozen=True)
class TargetJoint:
    """One joint of a target character: its name (the child body, MASS naming), 'ball' or
    'hinge', and for hinges the unit axis (3,) in the Z-up world-aligned rest frame."""

    name: str
    kind: str
    axis: np.ndarray


def biped_skeleton() -> tuple[str, tuple[TargetJoint, ...], dict[str, str]]:
    """(root body, joints in file order, MASS name map) of the 19-segment biped, read from
    `common/data/models/mass_human/human.xml` (each node's `bvh=` attribute)."""
    root = ET.parse(MASS_SKELETON).getroot()
    joints, name_map, root_name = [], {}, ""
    for node in root.iter("Node"):
        name = node.get("name")
        if name in _DROPPED_BODIES:
            continue
        jn = node.find("Joint")
        kind = jn.get("type")
        if kind == "Free":
            root_name = name
        elif kind == "Ball":
            joints.append(TargetJoint(name, "ball", np.zeros(3)))
        elif kind == "Revolute":
            axis = BVH_TO_MUJOCO @ np.array([float(v) for v in jn.get("axis").split()])
            joints.append(TargetJoint(name, "hinge", axis / np.linalg.norm(axis)))
        else:
            raise ClipError(f"joint type {kind!r} not handled (Free, Ball, Revolute)", path=MASS_SKELETON, joint=name)
        if jn.get("bvh"):
            name_map[name] = jn.get("bvh")
    # MASS leaves the head undriven; the BVH has a head joint, so use it.
    name_map.setdefault("Head", "Character1_Head")
    return root_name, tuple(joints), name_map


# CMU (cgspeed 31-joint) -> biped. Chains the biped merges are composed in order.
CMU_TO_BIPED: dict[str, str | tuple[str, ...]] = {
    "Pelvis": "Hips",
    "FemurR": ("RHipJoint", "RightUpLeg"), "TibiaR": "RightLeg", "TalusR": "RightFoot",
    "FemurL": ("LHipJoint", "LeftUpLeg"), "TibiaL": "LeftLeg", "TalusL": "LeftFoot",
    "Spine": "LowerBack", "Torso": ("Spine", "Spine1"), "Neck": "Neck", "Head": ("Neck1", "Head"),
    "ShoulderR": "RightShoulder", "ArmR": "RightArm", "ForeArmR": "RightForeArm", "HandR": "RightHand",
    "ShoulderL": "LeftShoulder", "ArmL": "LeftArm", "ForeArmL": "LeftForeArm", "HandL": "LeftHand",
}


def hinge_twist(q_wxyz: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Angle (rad) (N,) of the twist of rotations (N, 4) about a unit axis (3,): the hinge
    angle that best keeps the rotation when the swing part cannot be represented."""
    return 2.0 * np.arctan2(q_wxyz[:, 1:] @ axis, q_wxyz[:, 0])


def bvh_to_clip(bvh: Bvh, *, root: str, joints: tuple[TargetJoint, ...], name_map: dict[str, str | tuple[str, ...]],
                scale_m: float, character: str, name: str, label: str = "root", license: str = "",
                fps: float | None = None, loop: bool = False, axes: np.ndarray = BVH_TO_MUJOCO) -> Clip:
    """Drive `joints` (and the root body `root`) from BVH joints via `name_map`.

    axes: rotation (3, 3) from the file's axes to the character's (default BVH_TO_MUJOCO).
    Joints absent from the map stay at rest (identity / zero angle). Raises ClipError when the
    map names a BVH joint the file lacks or a target joint not in `joints`.
    """
    known = {j.name for j in joints} | {root}
    unknown = sorted(set(name_map) - known)
    if unknown:
        raise ClipError(f"name map targets {unknown} are not joints of {character!r} (known: {sorted(known)})", path=bvh.path)
    if root not in name_map:
        raise ClipError(f"name map must drive the root body {root!r}", path=bvh.path)
    n = bvh.num_frames

    def driven(target: str) -> Rotation:
        sources = name_map.get(target, ())
        sources = (sources,) if isinstance(sources, str) else tuple(sources)
        r = Rotation.identity(n)
        for src in sources:
            r = r * bvh.local_rotations(src)
        return r

    root_pos = bvh.root_positions() * scale_m @ axes.T
    root_quat = quat.continuous(quat.change_axes_quat(quat.wxyz(driven(root)), axes))
    parts = []
    for j in joints:
        q = quat.change_axes_quat(quat.wxyz(driven(j.name)), axes)
        parts.append(quat.continuous(q) if j.kind == "ball" else np.unwrap(hinge_twist(q, j.axis))[:, None])
    joint_qpos = np.concatenate(parts, axis=1)
    types = tuple(j.kind for j in joints)
    native = 1.0 / bvh.frame_time_s
    fps_used = native
    if fps is not None and abs(fps - native) > 1e-9:
        times = np.arange(n) * bvh.frame_time_s
        fps_used, root_pos, root_quat, joint_qpos = resample_by_time(times, root_pos, root_quat, joint_qpos, types, fps)
    return Clip(
        name=name, fps=fps_used, root_pos=root_pos, root_quat=root_quat, joint_names=tuple(j.name for j in joints),
        joint_types=types, joint_qpos=joint_qpos, hinge_axes=np.stack([j.axis for j in joints]), loop=loop,
        label=label, character=character, source=f"bvh:{Path(bvh.path).name}", license=license,
        extra={"native_fps": native, "scale_m": scale_m},
    )


def load_bvh(path: str | Path, *, skeleton: str = "mass", name: str | None = None, label: str = "root",
             license: str = "", fps: float | None = None, loop: bool = False, scale_m: float | None = None) -> Clip:
    """Import a BVH file onto the full biped.

    Args:
        skeleton: which name map to use: 'mass' (the MASS clips' `Character1_*` joints, scale
            0.01) or 'cmu' (the CMU 31-joint skeleton, scale 0.056444).
        fps: resample to this rate (Hz); default the file's own rate.
        scale_m: override the file-units-to-metres factor.
    """
    if skeleton not in ("mass", "cmu"):
        raise ClipError(f"unknown skeleton {skeleton!r}; choose 'mass' or 'cmu'", path=path)
    bvh = parse_bvh(path)
    root, joints, mass_map = biped_skeleton()
    name_map = mass_map if skeleton == "mass" else CMU_TO_BIPED
    default_scale = MASS_SCALE_M if skeleton == "mass" else CMU_SCALE_M
    return bvh_to_clip(bvh, root=root, joints=joints, name_map=name_map, scale_m=scale_m or default_scale,
                       character="biped", name=name or Path(path).stem, label=label, license=license, fps=fps, loop=loop)
