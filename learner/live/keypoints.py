"""Keypoints of another layout -> the video scheduler's joints: `morphmimic keypoints convert`.

    morphmimic keypoints convert markers.xml --mapping markers16 --out runs/poses.npz
    morphmimic send-poses runs/poses.npz --port 9870

The video scheduler (`common/tasks/executor/schedulers/video.py`) takes the humanoid's 15 body
origins in model order (`pose_packet.HUMANOID_JOINTS`: root, chest, neck, right_shoulder, ...,
left_ankle). A pose estimator or a marker set has other points in another order: this converts
a file of them with a small JSON mapping and writes the `.npz` that `send-poses` sends.

Sources: an MJCF file whose `<keyframe>` keys hold the markers as mocap body positions (`mpos`;
the marker names are the mocap bodies' names, the fps from the keys' times), a `.npy` array
[T, J, 3], or a `.npz` with `positions` [T, J, 3] and optionally `joints` (names) and `fps`.

The mapping (JSON; shipped ones in learner/live/keypoint_maps/, by name):

    {"description": "...",
     "source": ["pelvis", "head", ...],     # names of an array's J points in order (files
                                             # that name their points need none)
     "joints": {"root": "pelvis",           # each receiver joint: a source point, or
                "chest": {"mean": [{"mean": ["left_shoulder", "right_shoulder"]}, "pelvis"]},
                "right_ankle": {"mean": ["right_heel", "right_toe"], "weights": [3, 1]}, ...},
     "fps": 30,                              # when the source does not say (--fps overrides)
     "scale": 1.0,                           # source units -> metres (0.001 for millimetres)
     "up": "z",                              # "y": a y-up source is turned z-up
     "fit_bones": false}                     # true: each bone set to the model's length

`fit_bones` keeps every bone's direction and sets its length to the humanoid's (walking out from
the root), for a source whose body is not the model's size; the IK only uses directions, but
the root height and the feet's reach follow from the lengths.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar

import mujoco
import numpy as np
import tyro

from common.config_limits import Limit, above, check_limits, validated
from common.tasks.executor.schedulers.pose_packet import HUMANOID_JOINTS
from learner.cli import dispatch
from learner.cli_options import parse_options, refuse
from learner.live.pose_sender import load_keypoints

MAPS = Path(__file__).resolve().parent / "keypoint_maps"
"""Shipped mapping files (`--mapping NAME` finds NAME.json here)."""
RECEIVER_JOINTS = HUMANOID_JOINTS
MAPPING_KEYS = {"description", "source", "joints", "fps", "scale", "up", "fit_bones"}


@dataclass(frozen=True)
class Mapping:
    """A parsed mapping file (module docstring)."""

    joints: dict[str, Any]
    source: tuple[str, ...] | None = None
    fps: float | None = None
    scale: float = 1.0
    up: str = "z"
    fit_bones: bool = False
    description: str = ""


def shipped_mappings() -> list[str]:
    return sorted(p.stem for p in MAPS.glob("*.json"))


def _check_expr(expr: Any, where: str) -> None:
    if isinstance(expr, str) and expr:
        return
    if isinstance(expr, dict) and set(expr) <= {"mean", "weights"} and isinstance(expr.get("mean"), list) and expr["mean"]:
        weights = expr.get("weights")
        if weights is not None and (not isinstance(weights, list) or len(weights) != len(expr["mean"])
                                    or not all(isinstance(w, (int, float)) and w >= 0 for w in weights) or sum(weights) <= 0):
            raise ValueError(f"{where}: weights must be one non-negative number per point of mean, not all zero")
        for i, e in enumerate(expr["mean"]):
            _check_expr(e, f"{where}.mean[{i}]")
        return
    raise ValueError(f"{where}: {expr!r} is neither a source point's name nor {{\"mean\": [...], \"weights\": [...]}}")


def load_mapping(name_or_path: str | Path) -> Mapping:
    """A mapping file (a path, or the name of a shipped one); ValueError naming what is wrong."""
    path = Path(name_or_path)
    if not path.is_file() and (MAPS / f"{name_or_path}.json").is_file():
        path = MAPS / f"{name_or_path}.json"
    if not path.is_file():
        raise ValueError(f"mapping {str(name_or_path)!r} is neither a file nor a shipped mapping ({', '.join(shipped_mappings())})")
    try:
        raw = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc})") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{path}: a mapping is a JSON object")
    unknown = set(raw) - MAPPING_KEYS
    if unknown:
        raise ValueError(f"{path}: unknown keys {', '.join(sorted(unknown))}; a mapping has {', '.join(sorted(MAPPING_KEYS))}")
    joints = raw.get("joints")
    if not isinstance(joints, dict):
        raise ValueError(f"{path}: 'joints' must map each receiver joint to a source point or a mean")
    missing = [j for j in RECEIVER_JOINTS if j not in joints]
    extra = [j for j in joints if j not in RECEIVER_JOINTS]
    if missing or extra:
        raise ValueError(f"{path}: 'joints' must give exactly the receiver's {len(RECEIVER_JOINTS)} joints "
                         f"({', '.join(RECEIVER_JOINTS)}); " + "; ".join(
                             ([f"missing {', '.join(missing)}"] if missing else []) + ([f"not the receiver's: {', '.join(extra)}"] if extra else [])))
    for j, expr in joints.items():
        _check_expr(expr, f"{path}: joints.{j}")
    source = raw.get("source")
    if source is not None and not (isinstance(source, list) and source and all(isinstance(s, str) and s for s in source)
                                   and len(set(source)) == len(source)):
        raise ValueError(f"{path}: 'source' must be a list of distinct point names")
    fps, scale = raw.get("fps"), raw.get("scale", 1.0)
    if fps is not None and not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise ValueError(f"{path}: fps {fps!r} must be a positive number")
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise ValueError(f"{path}: scale {scale!r} must be a positive number")
    if raw.get("up", "z") not in ("z", "y"):
        raise ValueError(f"{path}: up {raw.get('up')!r} must be \"z\" or \"y\"")
    if not isinstance(raw.get("fit_bones", False), bool):
        raise ValueError(f"{path}: fit_bones must be true or false")
    return Mapping(joints=dict(joints), source=tuple(source) if source else None, fps=float(fps) if fps else None,
                   scale=float(scale), up=raw.get("up", "z"), fit_bones=raw.get("fit_bones", False),
                   description=str(raw.get("description", "")))


def read_mjcf_keyframes(path: str | Path) -> tuple[np.ndarray, tuple[str, ...], float | None]:
    """(positions [T, J, 3], the mocap bodies' names, fps from the keys' times or None) of an
    MJCF file whose keyframes hold mocap positions (`mpos`)."""
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        raise ValueError(f"{path}: MuJoCo cannot load it: {str(exc).splitlines()[0]}") from None
    if model.nmocap == 0 or model.nkey == 0:
        raise ValueError(f"{path}: no mocap bodies with keyframes (<keyframe><key mpos=...>): "
                         f"{model.nmocap} mocap bodies, {model.nkey} keys")
    names = [""] * model.nmocap
    for b in range(model.nbody):
        if model.body_mocapid[b] >= 0:
            names[model.body_mocapid[b]] = model.body(b).name or f"mocap{model.body_mocapid[b]}"
    positions = np.asarray(model.key_mpos, dtype=np.float64).reshape(model.nkey, model.nmocap, 3)
    times = np.asarray(model.key_time, dtype=np.float64)
    steps = np.diff(times)
    # NOTE: over the whole span, rounded: the keys' times are written with a few decimals
    fps = round(float((len(times) - 1) / (times[-1] - times[0])), 3) if len(steps) and np.all(steps > 0) else None
    return positions, tuple(names), fps


def read_source(path: str | Path) -> tuple[np.ndarray, tuple[str, ...] | None, float | None]:
    """(positions [T, J, 3], point names or None, fps or None) of a keypoint file (module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix in (".xml", ".mjcf"):
        return read_mjcf_keyframes(path)
    if suffix not in (".npy", ".npz"):
        raise ValueError(f"{path}: give an MJCF keyframe file (.xml), a .npy or a .npz")
    return load_keypoints(path)


def _evaluate(expr: Any, positions: np.ndarray, index: dict[str, int], where: str) -> np.ndarray:
    if isinstance(expr, str):
        if expr not in index:
            raise ValueError(f"{where}: the source has no point {expr!r} (it has {', '.join(index)})")
        return positions[:, index[expr]]
    parts = [_evaluate(e, positions, index, where) for e in expr["mean"]]
    w = np.asarray(expr.get("weights") or [1.0] * len(parts), dtype=np.float64)
    return np.tensordot(w / w.sum(), np.stack(parts), axes=1)


def model_bones() -> tuple[np.ndarray, np.ndarray]:
    """(parent index per receiver joint, -1 for the root; rest length of the bone to it, m)."""
    # lazy: start-up time of keypoints --help (common.characters adds scipy.optimize)
    from common.characters import load_character

    model = load_character("humanoid").model
    parents = np.array([int(model.body_parentid[b]) - 1 for b in range(1, model.nbody)])
    lengths = np.linalg.norm(model.body_pos[1:], axis=1)
    return parents, lengths


def fit_bone_lengths(positions: np.ndarray, parents: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """`positions` [T, J, 3] with each bone's direction kept and its length set to `lengths`
    (parents before children, as MuJoCo orders bodies)."""
    out = positions.copy()
    for j, p in enumerate(parents):
        if p < 0:
            continue
        bone = positions[:, j] - positions[:, p]
        norm = np.linalg.norm(bone, axis=1, keepdims=True)
        out[:, j] = out[:, p] + np.where(norm > 1e-9, bone / np.maximum(norm, 1e-12), 0.0) * lengths[j]
    return out


def convert(positions: np.ndarray, names: tuple[str, ...] | None, mapping: Mapping) -> np.ndarray:
    """Source points [T, J, 3] -> the receiver's joints [T, 15, 3] in metres, z up."""
    positions = np.asarray(positions, dtype=np.float64)
    if names is None:
        names = mapping.source
        if names is None:
            raise ValueError("the source does not name its points and the mapping has no 'source' list to name them")
    if len(names) != positions.shape[1]:
        raise ValueError(f"the source has {positions.shape[1]} points per frame but {len(names)} names "
                         f"({'the mapping' + chr(39) + 's source list' if names is mapping.source else 'its own'})")
    index = {n: i for i, n in enumerate(names)}
    out = np.stack([_evaluate(mapping.joints[j], positions, index, f"joints.{j}") for j in RECEIVER_JOINTS], axis=1)
    out = out * mapping.scale
    if mapping.up == "y":
        out = np.stack([out[..., 0], -out[..., 2], out[..., 1]], axis=-1)
    if mapping.fit_bones:
        out = fit_bone_lengths(out, *model_bones())
    if not np.all(np.isfinite(out)):
        raise ValueError("the converted positions hold NaN or inf (missing points in the source?)")
    return out


def write_keypoints(path: str | Path, positions: np.ndarray, fps: float) -> None:
    """The file `send-poses` sends: positions [T, 15, 3] (m), fps and the joint names."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, positions=np.asarray(positions, dtype=np.float64), fps=np.array(float(fps)),
             joints=np.array(RECEIVER_JOINTS))


PROG = "morphmimic keypoints convert"


@validated
@dataclass
class ConvertOptions:
    source: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="SOURCE")]
    """Keypoints of another layout: an MJCF keyframe file (.xml, mocap `mpos`), .npy [T, J, 3] or .npz."""
    mapping: str
    """The mapping JSON (rename, reorder, points made from neighbours, fps, scale), or a shipped one's name."""
    out: Path = Path("runs/poses.npz")
    """Where to write the converted keypoints (.npz, for `morphmimic send-poses`)."""
    fps: float | None = None
    """Frames per second (default: the source's, else the mapping's)."""
    fit_bones: bool | None = None
    """Set each bone to the humanoid's length (default: the mapping's `fit_bones`)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"fps": above(0)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def convert_main(argv: list[str]) -> int:
    description = f"{__doc__}\nshipped mappings: {', '.join(shipped_mappings())}"
    args = parse_options(ConvertOptions, argv, prog=PROG, description=description)
    if args.out.suffix.lower() != ".npz":
        refuse(PROG, f"--out {args.out}: write an .npz")
    try:
        mapping = load_mapping(args.mapping)
        if args.fit_bones is not None:
            mapping = Mapping(**{**mapping.__dict__, "fit_bones": args.fit_bones})
        positions, names, source_fps = read_source(args.source)
        fps = args.fps or source_fps or mapping.fps
        if fps is None:
            raise ValueError(f"{args.source} does not say its fps and the mapping has none: give --fps")
        out = convert(positions, names, mapping)
    except ValueError as exc:
        refuse(PROG, str(exc))
    write_keypoints(args.out, out, fps)
    print(f"[keypoints] {args.source}: {len(out)} frames of {positions.shape[1]} points -> {args.out}: "
          f"{len(RECEIVER_JOINTS)} joints at {fps:g} fps{' (bones fitted to the humanoid)' if mapping.fit_bones else ''}")
    return 0


SUBCOMMANDS: dict[str, tuple[str | Any, str]] = {
    "convert": (convert_main, "keypoints of another layout (MJCF keyframe mpos, .npy/.npz [T, J, 3]) -> the video scheduler's 15 joints"),
}


def main(argv: list[str]) -> int:
    return dispatch("morphmimic keypoints", "subcommand", SUBCOMMANDS, argv)

