"""Send 3-D joint positions over UDP in the video scheduler's packet format (`pose_packet.py`):
the sending end of UniCon 2020's video scheduler (METHOD.md B "Schedulers"), standing in for a
pose estimator. `morphmimic send-poses`:

    morphmimic send-poses humanoid3d_walk --port 9870 --loop --seconds 30
    morphmimic send-poses keypoints.npz --fps 30 --port 9870      # [T, J, 3] metres, J = 15
    morphmimic keypoints convert markers.xml --mapping markers16 --out runs/poses.npz   # another layout

A library clip is played on the humanoid (`MotionLibrary`, no retargeting), its body origins
computed per frame by MuJoCo's forward kinematics (`mj_kinematics`) and sent at `fps` in real
time, timestamps k / fps on the stream clock; `speed` plays the clip faster or slower, `loop`
repeats it (the root carried on by one cycle's displacement per loop). A keypoint file holds
positions `[T, J, 3]` in metres in the packet's joint order (`.npy`, or `.npz` with an array
`positions`, or its only array, and optionally a scalar `fps` and the names `joints`). A file
whose joints are not the receiver's (another count, or names in another order) is refused
before anything is sent, exit 2: `morphmimic keypoints convert` turns another layout into
this one (learner/live/keypoints.py).
"""

from __future__ import annotations

import math
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, ClassVar, Iterator

import mujoco
import numpy as np
import tyro

from common.config_limits import Limit, above, between, check_limits, validated
from common.tasks.executor.schedulers import pose_packet
from learner.cli_options import parse_options

DEFAULT_PORT = 9870
CHARACTER = "humanoid"
CHUNK_S = 1.0
"""Seconds of a clip sampled at once (vectorised) while sending."""


def clip_positions(clip_id: str, fps: float = 60.0, speed: float = 1.0, loop: bool = False,
                   seconds: float | None = None) -> Iterator[np.ndarray]:
    """Body origins `[J, 3]` (world excluded, model order) of `clip_id` on the humanoid, one array
    per frame at `fps` (stream time k / fps, clip time k / fps x speed); ends at the clip's end
    (unless `loop`) or after `seconds`. Raises ValueError for an unknown clip."""
    # lazy: start-up time of morphmimic send-poses --help (scipy via common.motion and common.characters)
    from common.characters import load_character
    from common.motion.library import MotionLibrary, clips_for  # lazy: as above
    from common.motion.reference import CharacterMotion  # lazy: as above

    known = [c for c, _ in clips_for(CHARACTER)]
    if clip_id not in known:
        raise ValueError(f"clip {clip_id!r} does not play on the {CHARACTER}; choose from: {', '.join(known)}")
    model = load_character(CHARACTER).model
    motion = CharacterMotion.from_clip(MotionLibrary().clip(clip_id).with_(loop=loop), model)
    data = mujoco.MjData(model)
    end = math.inf if loop else motion.duration_s / speed
    if seconds is not None:
        end = min(end, float(seconds))
    k, chunk = 0, max(int(round(CHUNK_S * fps)), 1)
    while k / fps <= end + 1e-9:
        ks = np.arange(k, k + chunk)
        ks = ks[ks / fps <= end + 1e-9]
        if len(ks) == 0:
            break
        for q in np.atleast_2d(motion.qpos(ks / fps * speed)):
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            yield data.xpos[1:].copy()
        k += len(ks)


def load_keypoints(path: str | Path) -> tuple[np.ndarray, tuple[str, ...] | None, float | None]:
    """(positions `[T, J, 3]` metres, joint names or None, fps or None) from a .npy or .npz file
    (module docstring)."""
    path = Path(path)
    names = None
    if path.suffix.lower() == ".npy":
        positions, fps = np.load(path, allow_pickle=False), None
    elif path.suffix.lower() == ".npz":
        with np.load(path, allow_pickle=False) as z:
            arrays = [k for k in z.files if k not in ("fps", "joints")]
            if "positions" in z.files:
                name = "positions"
            elif len(arrays) == 1:
                name = arrays[0]
            else:
                raise ValueError(f"{path}: no 'positions' array (arrays: {', '.join(z.files)})")
            positions = z[name]
            fps = float(z["fps"]) if "fps" in z.files else None
            names = tuple(str(n) for n in z["joints"].reshape(-1)) if "joints" in z.files else None
    else:
        raise ValueError(f"{path}: keypoints must be a .npy or .npz file")
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3 or len(positions) == 0:
        raise ValueError(f"{path}: keypoints must be [T, J, 3], not {list(positions.shape)}")
    return positions, names, fps


def check_layout(path: str | Path, positions: np.ndarray, names: tuple[str, ...] | None,
                 expected: tuple[str, ...] = pose_packet.HUMANOID_JOINTS) -> None:
    """ValueError (one line: the count and the expected joints) unless the file's joints are the
    receiver's: `expected` in number and, when the file names them, in name and order."""
    hint = f"convert it with `morphmimic keypoints convert {path} --mapping MAP.json --out runs/poses.npz`"
    want = f"the video scheduler expects {len(expected)}: {', '.join(expected)}"
    if positions.shape[1] != len(expected):
        raise ValueError(f"{path} has {positions.shape[1]} joints per frame; {want}; {hint}")
    if names is not None and tuple(names) != tuple(expected):
        raise ValueError(f"{path} names its joints {', '.join(names)}; {want}, in that order; {hint}")


def send_positions(frames: Iterator[np.ndarray] | np.ndarray, port: int, host: str = "127.0.0.1", fps: float = 60.0, *,
                   realtime: bool = True, stop: threading.Event | None = None, loop: bool = False,
                   seconds: float | None = None) -> int:
    """Send each frame `[J, 3]` as one packet (index k, timestamp k / fps), paced at `fps` in
    real time unless `realtime` is False; an array `[T, J, 3]` repeats with `loop` (until
    `seconds`). Stops early when `stop` is set. Returns the packets sent."""
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps {fps!r} must be positive")
    if isinstance(frames, np.ndarray):
        frames = _repeat(frames, fps, loop, seconds)
    sent = 0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        start = time.perf_counter()
        for k, p in enumerate(frames):
            if stop is not None and stop.is_set():
                break
            if realtime:
                ahead = start + k / fps - time.perf_counter()
                if ahead > 0:
                    time.sleep(ahead)
            sock.sendto(pose_packet.encode(k, k / fps, p), (host, int(port)))
            sent += 1
    return sent


def _repeat(positions: np.ndarray, fps: float, loop: bool, seconds: float | None) -> Iterator[np.ndarray]:
    k = 0
    while True:
        if seconds is not None and k / fps > seconds + 1e-9:
            return
        if k >= len(positions) and not loop:
            return
        yield positions[k % len(positions)]
        k += 1


def send_clip(clip_id: str, host: str = "127.0.0.1", port: int = DEFAULT_PORT, fps: float = 60.0, speed: float = 1.0,
              loop: bool = False, seconds: float | None = None, *, realtime: bool = True,
              stop: threading.Event | None = None) -> int:
    """Play a library clip on the humanoid and send its body positions to host:port (module
    docstring); returns the packets sent."""
    if not (math.isfinite(speed) and 0.05 <= speed <= 10.0):
        raise ValueError(f"speed {speed!r} must be in [0.05, 10]")
    if loop and seconds is None and not realtime:
        raise ValueError("a looping clip sent as fast as possible never ends: give seconds")
    return send_positions(clip_positions(clip_id, fps, speed, loop, seconds), port, host, fps, realtime=realtime, stop=stop)


PROG = "morphmimic send-poses"


@validated
@dataclass
class SendPosesOptions:
    source: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="SOURCE")]
    """A humanoid clip id (`morphmimic motion check --all` prints them) or a keypoint file .npy/.npz [T, 15, 3] in the receiver's joint order (`morphmimic keypoints convert` makes one)."""
    host: str = "127.0.0.1"
    """Where the video scheduler listens."""
    port: int = DEFAULT_PORT
    """The video scheduler's UDP port."""
    fps: float | None = None
    """Packets per second (default: 60, or the file's fps)."""
    speed: float = 1.0
    """Clip playback speed."""
    loop: bool = False
    """Repeat the clip or file."""
    seconds: float | None = None
    """Stop after this many seconds of stream."""

    LIMITS: ClassVar[dict[str, Limit]] = {"port": between(1, 65535, integer=True), "fps": above(0),
                                          "speed": above(0), "seconds": above(0)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(SendPosesOptions, argv, prog=PROG, description=__doc__)
    try:
        if args.source.lower().endswith((".xml", ".mjcf")):
            raise ValueError(f"{args.source}: send-poses sends the video scheduler's own layout (.npy/.npz); "
                             f"convert it with `morphmimic keypoints convert {args.source} --mapping MAP.json --out runs/poses.npz`")
        if args.source.lower().endswith((".npy", ".npz")):
            positions, names, file_fps = load_keypoints(args.source)
            check_layout(args.source, positions, names)
            fps = args.fps or file_fps or 60.0
            print(f"[send-poses] {args.source}: {len(positions)} frames of {positions.shape[1]} joints at {fps:g} fps "
                  f"-> udp://{args.host}:{args.port}", flush=True)
            sent = send_positions(positions, args.port, args.host, fps, loop=args.loop, seconds=args.seconds)
        else:
            fps = args.fps or 60.0
            print(f"[send-poses] {args.source} at {fps:g} fps, x{args.speed:g}{' looped' if args.loop else ''} "
                  f"-> udp://{args.host}:{args.port}", flush=True)
            sent = send_clip(args.source, args.host, args.port, fps, args.speed, args.loop, args.seconds)
    except (ValueError, OSError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 0
    print(f"[send-poses] sent {sent} packets", flush=True)
    return 0
