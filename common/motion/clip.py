"""The canonical clip: one motion on one character's joint structure, stored as `.npz`.

Format (version 1), all arrays float64, MuJoCo's world convention (Z up, metres, radians):

| key | shape | meaning |
|---|---|---|
| `root_pos` | (T, 3) | root (pelvis) position in the world, m |
| `root_quat` | (T, 4) | root orientation, (w, x, y, z), unit |
| `joint_qpos` | (T, Q) | joint rotations in the character's joint order, packed like MuJoCo qpos: 4 numbers (w, x, y, z) per ball joint, 1 angle (rad) per hinge joint |
| `hinge_axes` | (J, 3) | for hinge joints the unit rotation axis; zeros for ball joints |
| `meta` | () str | JSON: version, name, fps, joint_names, joint_types, loop, label, character, source, license |

Joint rotations are *local* rotations expressed in world-aligned joint frames of the rest
pose (the convention of DeepMimic and BVH, after the Y-up to Z-up change): at rest every
rotation is the identity, and a ball joint's quaternion rotates the child about the joint in
axes parallel to the world's when every ancestor is at rest. `common.motion.qpos_map` turns
this into a particular MJCF's qpos, whatever its body frames are. Frames are uniform in time:
frame k is at k / fps seconds, so a clip lasts (T - 1) / fps seconds. A looping clip's last
frame is the pose that follows the first again (DeepMimic's "wrap").
Loading is `np.load` of uncompressed arrays: about a millisecond per clip.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from common.motion.errors import ClipError

FORMAT_VERSION = 1
JOINT_TYPES = ("ball", "hinge")
_QPOS_WIDTH = {"ball": 4, "hinge": 1}


@dataclass(frozen=True)
class Clip:
    """One reference motion (UniCon's clip; Won & Lee's reference motion), see module docstring."""

    name: str
    """Clip id, e.g. `humanoid3d_walk`."""
    fps: float
    """Frames per second (Hz); frames are uniformly spaced."""
    root_pos: np.ndarray
    """(T, 3) root position, m, Z up."""
    root_quat: np.ndarray
    """(T, 4) root orientation (w, x, y, z)."""
    joint_names: tuple[str, ...]
    """(J,) joint names in the character's joint order."""
    joint_types: tuple[str, ...]
    """(J,) 'ball' or 'hinge'."""
    joint_qpos: np.ndarray
    """(T, Q) packed joint rotations: 4 per ball joint (w, x, y, z), 1 angle in rad per hinge."""
    hinge_axes: np.ndarray
    """(J, 3) unit hinge axis in the world-aligned rest frame; zeros for ball joints."""
    loop: bool = False
    """True when the clip may repeat (the last frame leads back into the first)."""
    label: str = "root"
    """Hierarchical class label, e.g. `root/locomotion/walk/forward` (UniCon)."""
    character: str = ""
    """Character preset the joint order belongs to (`humanoid`, `biped`, ...)."""
    source: str = ""
    """Where the motion came from (file, repository, or `procedural:<generator>`)."""
    license: str = ""
    """License of the source data (MIT, Apache-2.0, CMU ...)."""
    extra: dict = field(default_factory=dict)
    """Free-form JSON-able notes (e.g. import scale); kept through save/load."""

    def __post_init__(self) -> None:
        t = self.root_pos.shape[0] if np.ndim(self.root_pos) == 2 else -1
        where = dict(path=self.name)
        if self.fps <= 0 or not np.isfinite(self.fps):
            raise ClipError(f"fps must be a positive number, got {self.fps}", **where)
        if t < 1 or self.root_pos.shape != (t, 3):
            raise ClipError(f"root_pos must have shape (T, 3) with T >= 1, got {np.shape(self.root_pos)}", **where)
        if self.root_quat.shape != (t, 4):
            raise ClipError(f"root_quat must have shape ({t}, 4), got {self.root_quat.shape}", **where)
        if len(self.joint_names) != len(self.joint_types):
            raise ClipError(f"{len(self.joint_names)} joint names but {len(self.joint_types)} joint types", **where)
        bad = [k for k in self.joint_types if k not in JOINT_TYPES]
        if bad:
            raise ClipError(f"joint types must be one of {JOINT_TYPES}, got {bad}", **where)
        q = sum(_QPOS_WIDTH[k] for k in self.joint_types)
        if self.joint_qpos.shape != (t, q):
            raise ClipError(f"joint_qpos must have shape ({t}, {q}) for these joints, got {self.joint_qpos.shape}", **where)
        if self.hinge_axes.shape != (len(self.joint_names), 3):
            raise ClipError(f"hinge_axes must have shape ({len(self.joint_names)}, 3), got {self.hinge_axes.shape}", **where)
        for key in ("root_pos", "root_quat", "joint_qpos"):
            arr = getattr(self, key)
            if not np.all(np.isfinite(arr)):
                frame = int(np.argwhere(~np.isfinite(arr))[0][0])
                raise ClipError(f"{key} holds NaN or inf", path=self.name, frame=frame)
        norms = np.linalg.norm(self.root_quat, axis=-1)
        if np.any(np.abs(norms - 1.0) > 1e-6):
            frame = int(np.argmax(np.abs(norms - 1.0)))
            raise ClipError(f"root_quat is not unit length (|q| = {norms[frame]:.4f}); normalize on import", path=self.name, frame=frame)
        for j, sl in enumerate(self.joint_slices()):
            if self.joint_types[j] == "ball":
                n = np.linalg.norm(self.joint_qpos[:, sl], axis=-1)
                if np.any(np.abs(n - 1.0) > 1e-6):
                    frame = int(np.argmax(np.abs(n - 1.0)))
                    raise ClipError(f"quaternion is not unit length (|q| = {n[frame]:.4f})", path=self.name, frame=frame, joint=self.joint_names[j])

    @property
    def num_frames(self) -> int:
        """T, the number of frames."""
        return int(self.root_pos.shape[0])

    @property
    def duration_s(self) -> float:
        """(T - 1) / fps: time of the last frame, s."""
        return (self.num_frames - 1) / self.fps

    @property
    def dt_s(self) -> float:
        """Seconds between frames."""
        return 1.0 / self.fps

    def joint_slices(self) -> list[slice]:
        """Column slice of `joint_qpos` for each joint, in joint order."""
        out, start = [], 0
        for kind in self.joint_types:
            out.append(slice(start, start + _QPOS_WIDTH[kind]))
            start += _QPOS_WIDTH[kind]
        return out

    def with_(self, **changes) -> "Clip":
        """A copy with some fields replaced (validated again)."""
        return replace(self, **changes)

    def save(self, path: str | Path, compact: bool = False) -> Path:
        """Write the clip as an uncompressed `.npz` (fast to load); returns the path. `compact`:
        float32 arrays, zip-compressed (about half the size; `load_clip` reads float64 back)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = dict(
            version=FORMAT_VERSION, name=self.name, fps=self.fps, joint_names=list(self.joint_names),
            joint_types=list(self.joint_types), loop=self.loop, label=self.label, character=self.character,
            source=self.source, license=self.license, extra=self.extra,
        )
        with open(path, "wb") as fh:
            arrays = dict(root_pos=self.root_pos, root_quat=self.root_quat, joint_qpos=self.joint_qpos, hinge_axes=self.hinge_axes)
            if compact:
                np.savez_compressed(fh, **{k: v.astype(np.float32) for k, v in arrays.items()}, meta=np.array(json.dumps(meta)))
            else:
                np.savez(fh, **arrays, meta=np.array(json.dumps(meta)))
        return path


def load_clip(path: str | Path) -> Clip:
    """Read a clip written by `Clip.save`; raises ClipError on a missing key or a wrong version."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: np.asarray(z[k], dtype=np.float64) for k in ("root_pos", "root_quat", "joint_qpos", "hinge_axes")}
    except (OSError, KeyError, ValueError) as exc:
        raise ClipError(f"not a canonical clip .npz ({exc}); write one with `morphmimic motion import`", path=path) from exc
    if meta.get("version") != FORMAT_VERSION:
        raise ClipError(f"clip format version {meta.get('version')!r}, this code reads {FORMAT_VERSION}", path=path)
    try:
        return Clip(
            name=meta["name"], fps=float(meta["fps"]), joint_names=tuple(meta["joint_names"]),
            joint_types=tuple(meta["joint_types"]), loop=bool(meta["loop"]), label=meta["label"],
            character=meta["character"], source=meta["source"], license=meta["license"],
            extra=meta.get("extra", {}), **arrays,
        )
    except ClipError as exc:
        raise ClipError(f"invalid clip: {exc}", path=path) from exc
