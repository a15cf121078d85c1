"""Import a DeepMimic humanoid3d motion (JSON) into the canonical clip (Peng et al. 2018).

File: `{"Loop": "wrap"|"none", "Frames": [[dt, root pos (3), root quat (4, w x y z), chest (4),
neck (4), r_hip (4), r_knee (1), r_ankle (4), r_shoulder (4), r_elbow (1), l_hip (4), l_knee (1),
l_ankle (4), l_shoulder (4), l_elbow (1)], ...]}`: 44 numbers per frame, Y up, x forward, metres,
local joint rotations (see common/data/README.md).

What the importer does and why:
- Y up -> Z up: positions (x, y, z) -> (x, -z, y), quaternions (w, x, y, z) -> (w, x, -z, y);
  the revolute knees and elbows (about +z in DeepMimic) then turn about (0, -1, 0).
- quaternions normalized: 11 of the 16 clips hold non-unit ones (up to |q| = 1.42).
- resampled by time: clip rates differ (16..120 Hz) and the last frame's dt is 0 (unused).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from common.motion import quat
from common.motion.clip import Clip
from common.motion.errors import ClipError
from common.motion.kinematics import resample_by_time

# (name, type) in file order == the DeepMimic humanoid's joint order (characters issue 3).
HUMANOID_JOINTS: tuple[tuple[str, str], ...] = (
    ("chest", "ball"), ("neck", "ball"),
    ("right_hip", "ball"), ("right_knee", "hinge"), ("right_ankle", "ball"),
    ("right_shoulder", "ball"), ("right_elbow", "hinge"),
    ("left_hip", "ball"), ("left_knee", "hinge"), ("left_ankle", "ball"),
    ("left_shoulder", "ball"), ("left_elbow", "hinge"),
)
HINGE_AXIS_Z_UP = np.array([0.0, -1.0, 0.0])
FRAME_WIDTH = 1 + 3 + 4 + sum(4 if kind == "ball" else 1 for _, kind in HUMANOID_JOINTS)  # 44
LOOP_VALUES = {"wrap": True, "none": False}


def _columns() -> list[str]:
    """Name of every number in a frame, for error messages."""
    cols = ["dt", "root_pos.x", "root_pos.y", "root_pos.z", "root_quat.w", "root_quat.x", "root_quat.y", "root_quat.z"]
    for name, kind in HUMANOID_JOINTS:
        cols += [f"{name}.{c}" for c in "wxyz"] if kind == "ball" else [f"{name}.angle"]
    return cols


def load_deepmimic(path: str | Path, *, fps: float | None = None, name: str | None = None,
                   label: str = "root", license: str = "MIT") -> Clip:
    """Read, validate and convert one DeepMimic motion file.

    Args:
        path: the `.txt` JSON file.
        fps: output frame rate (Hz); default the file's own rate (1 / median dt).
        name: clip name; default the file stem.
        label: hierarchical class label (see `common.motion.manifest`).
    Raises:
        ClipError naming the file, frame and column on malformed input.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ClipError(f"cannot read DeepMimic JSON ({exc})", path=path) from exc
    if not isinstance(doc, dict) or "Frames" not in doc:
        raise ClipError('expected a JSON object with a "Frames" list (DeepMimic motion file)', path=path)
    loop_value = doc.get("Loop", "none")
    if loop_value not in LOOP_VALUES:
        raise ClipError(f'"Loop" is {loop_value!r}; expected one of {sorted(LOOP_VALUES)}', path=path)
    frames = doc["Frames"]
    if not isinstance(frames, list) or len(frames) < 2:
        raise ClipError(f"expected at least 2 frames, got {len(frames) if isinstance(frames, list) else type(frames).__name__}", path=path)
    cols = _columns()
    rows = []
    for k, row in enumerate(frames):
        if not isinstance(row, list) or len(row) != FRAME_WIDTH:
            got = len(row) if isinstance(row, list) else type(row).__name__
            raise ClipError(f"expected {FRAME_WIDTH} numbers per frame (dt, root pos, root quat, 12 joints), got {got}", path=path, frame=k)
        try:
            arr = np.array(row, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ClipError(f"non-numeric value in frame ({exc})", path=path, frame=k) from exc
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise ClipError(f"value {arr[bad[0]]} is not a finite number", path=path, frame=k, joint=cols[bad[0]])
        rows.append(arr)
    data = np.stack(rows)
    dt = data[:-1, 0]
    if np.any(dt <= 0):
        k = int(np.flatnonzero(dt <= 0)[0])
        raise ClipError(f"dt is {dt[k]}; every frame but the last needs dt > 0 s", path=path, frame=k, joint="dt")
    times = np.concatenate([[0.0], np.cumsum(dt)])

    root_pos = quat.y_up_to_z_up_pos(data[:, 1:4])
    parts, col = [], 8
    root_quat = _unit(data[:, 4:8], path, "root_quat")
    for name_j, kind in HUMANOID_JOINTS:
        if kind == "ball":
            parts.append(quat.y_up_to_z_up_quat(_unit(data[:, col:col + 4], path, name_j)))
            col += 4
        else:
            parts.append(data[:, col:col + 1])
            col += 1
    root_quat = quat.continuous(quat.y_up_to_z_up_quat(root_quat))
    joint_qpos = np.concatenate(parts, axis=1)
    types = tuple(kind for _, kind in HUMANOID_JOINTS)
    _make_continuous(joint_qpos, types)

    native = 1.0 / float(np.median(dt))
    fps_used, root_pos, root_quat, joint_qpos = resample_by_time(times, root_pos, root_quat, joint_qpos, types, fps or native)
    axes = np.array([HINGE_AXIS_Z_UP if kind == "hinge" else np.zeros(3) for _, kind in HUMANOID_JOINTS])
    return Clip(
        name=name or path.stem, fps=fps_used, root_pos=root_pos, root_quat=root_quat,
        joint_names=tuple(n for n, _ in HUMANOID_JOINTS), joint_types=types, joint_qpos=joint_qpos,
        hinge_axes=axes, loop=LOOP_VALUES[loop_value], label=label, character="humanoid",
        source=f"deepmimic:{path.name}", license=license, extra={"native_fps": native},
    )


def _unit(q: np.ndarray, path: Path, joint: str) -> np.ndarray:
    """Normalize (T, 4) quaternions; a zero-length one is an error, not a guess."""
    n = np.linalg.norm(q, axis=1)
    if np.any(n < 1e-6):
        raise ClipError("zero-length quaternion", path=path, frame=int(np.argmin(n)), joint=joint)
    return q / n[:, None]


def _make_continuous(joint_qpos: np.ndarray, types: tuple[str, ...]) -> None:
    """In place: flip ball-joint quaternion signs so frames lie in one hemisphere (for slerp)."""
    start = 0
    for kind in types:
        if kind == "ball":
            joint_qpos[:, start:start + 4] = quat.continuous(joint_qpos[:, start:start + 4])
            start += 4
        else:
            start += 1
