"""A BVH parser: hierarchy, any channel order, frames; validates and fails with ClipError.

BVH (Biovision hierarchy): a joint tree with OFFSETs and CHANNELS, then `Frames: N`,
`Frame Time: dt` and N lines of numbers. Rotations are Euler angles in degrees applied in the
order the channels are listed (intrinsic: `Zrotation Xrotation Yrotation` means
R = Rz @ Rx @ Ry); every joint may list its own order. Rest frames carry no rotation, so a
joint's channels give its local rotation in axes parallel to the file's world (Y up).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from common.motion.errors import ClipError

CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_CANON = {c.lower(): c for c in CHANNEL_NAMES}


@dataclass(frozen=True)
class Bvh:
    """A parsed BVH file, in the file's own units and axes."""

    path: str
    joint_names: tuple[str, ...]
    """(J,) joints in file order (ROOT first); End Sites are not joints."""
    parents: tuple[int, ...]
    """(J,) parent index, -1 for the root."""
    offsets: np.ndarray
    """(J, 3) rest offset from the parent, file units."""
    channels: tuple[tuple[str, ...], ...]
    """(J,) channel names per joint, in file order."""
    frame_time_s: float
    """Seconds per frame."""
    motion: np.ndarray
    """(N, C) channel values per frame; C = total number of channels."""

    @property
    def num_frames(self) -> int:
        return int(self.motion.shape[0])

    def columns(self, joint: str) -> dict[str, int]:
        """{channel name: column in `motion`} for one joint; ClipError if unknown."""
        if joint not in self.joint_names:
            raise ClipError(f"unknown joint; the file has {', '.join(self.joint_names)}", path=self.path, joint=joint)
        start = 0
        for name, chans in zip(self.joint_names, self.channels):
            if name == joint:
                return {c: start + i for i, c in enumerate(chans)}
            start += len(chans)
        raise AssertionError("unreachable")

    def local_rotations(self, joint: str) -> Rotation:
        """(N,) local rotations of a joint from its rotation channels, in its channel order."""
        cols = self.columns(joint)
        rot_chans = [c for c in self.channels[self.joint_names.index(joint)] if c.endswith("rotation")]
        if not rot_chans:
            return Rotation.identity(self.num_frames)
        seq = "".join(c[0] for c in rot_chans)  # uppercase: intrinsic, as BVH means it
        angles = self.motion[:, [cols[c] for c in rot_chans]]
        return Rotation.from_euler(seq, angles, degrees=True)

    def has_positions(self, joint: str) -> bool:
        """True when the joint has position channels (a non-root joint with them, as every
        Bandai Namco joint has, is translated by them instead of its OFFSET)."""
        return any(c.endswith("position") for c in self.channels[self.joint_names.index(joint)])

    def local_translations(self, joint: str) -> np.ndarray:
        """(N, 3) translation from the parent per frame, file units: the position channels
        where the joint has them, else its rest OFFSET (per axis)."""
        cols = self.columns(joint)
        out = np.tile(self.offsets[self.joint_names.index(joint)], (self.num_frames, 1))
        for axis, c in enumerate(("Xposition", "Yposition", "Zposition")):
            if c in cols:
                out[:, axis] = self.motion[:, cols[c]]
        return out

    def root_positions(self) -> np.ndarray:
        """(N, 3) root position from its position channels (file units); rest offset if none."""
        cols = self.columns(self.joint_names[0])
        out = np.tile(self.offsets[0], (self.num_frames, 1))
        for axis, c in enumerate(("Xposition", "Yposition", "Zposition")):
            if c in cols:
                out[:, axis] = self.motion[:, cols[c]]
        return out


class _Tokens:
    """Whitespace tokens with their line numbers, for error messages."""

    def __init__(self, text: str, path: str) -> None:
        self.items = [(tok, n + 1) for n, line in enumerate(text.splitlines()) for tok in line.split()]
        self.i = 0
        self.path = path

    def peek(self) -> str | None:
        return self.items[self.i][0] if self.i < len(self.items) else None

    def next(self, what: str) -> str:
        if self.i >= len(self.items):
            raise ClipError(f"file ends early: expected {what}", path=self.path)
        tok = self.items[self.i][0]
        self.i += 1
        return tok

    def line(self) -> int:
        return self.items[min(self.i, len(self.items) - 1)][1] if self.items else 0

    def expect(self, word: str) -> None:
        tok = self.next(repr(word))
        if tok != word:
            raise ClipError(f"line {self.items[self.i - 1][1]}: expected {word!r}, found {tok!r}", path=self.path)

    def number(self, what: str, joint: str | None = None) -> float:
        tok = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise ClipError(f"line {self.items[self.i - 1][1]}: expected a number for {what}, found {tok!r}", path=self.path, joint=joint) from None
        if not np.isfinite(value):
            raise ClipError(f"line {self.items[self.i - 1][1]}: {what} is {tok}", path=self.path, joint=joint)
        return value


def parse_bvh(path: str | Path) -> Bvh:
    """Read and validate a BVH file.

    Raises ClipError (naming the file, line or frame, and joint/channel) on: a bad hierarchy,
    a CHANNELS count that does not match the names after it, unknown channel names, duplicate
    joint names, a bad Frames/Frame Time header, frame lines with the wrong number of values,
    fewer or more frame lines than `Frames:` declares, NaN or non-numeric values.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ClipError(f"cannot read BVH ({exc})", path=path) from exc
    head, sep, body = text.partition("MOTION")
    if not sep:
        raise ClipError("no MOTION section; a BVH file has HIERARCHY then MOTION", path=path)
    toks = _Tokens(head, str(path))
    toks.expect("HIERARCHY")
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []

    def joint(parent: int) -> None:
        name = toks.next("a joint name")
        if name in names:
            raise ClipError(f"line {toks.line()}: joint name {name!r} appears twice", path=path, joint=name)
        index = len(names)
        names.append(name)
        parents.append(parent)
        toks.expect("{")
        toks.expect("OFFSET")
        offsets.append([toks.number(f"OFFSET {a}", name) for a in "xyz"])
        toks.expect("CHANNELS")
        count_tok = toks.next("a channel count")
        if not count_tok.isdigit():
            raise ClipError(f"line {toks.line()}: CHANNELS needs a count, found {count_tok!r}", path=path, joint=name)
        count = int(count_tok)
        chans = []
        for k in range(count):
            tok = toks.peek()
            if tok is None or tok.lower() not in _CANON:
                raise ClipError(f"line {toks.line()}: CHANNELS declares {count} channels but found {k} channel names "
                                f"(then {tok!r}); allowed names: {', '.join(CHANNEL_NAMES)}", path=path, joint=name)
            chans.append(_CANON[toks.next("a channel").lower()])
        if len(set(chans)) != len(chans):
            raise ClipError(f"line {toks.line()}: repeated channel in {chans}", path=path, joint=name)
        channels.append(tuple(chans))
        while True:
            tok = toks.next("JOINT, End Site or '}'")
            if tok == "}":
                return
            if tok == "JOINT":
                joint(index)
            elif tok == "End":
                toks.expect("Site")
                toks.expect("{")
                toks.expect("OFFSET")
                for a in "xyz":
                    toks.number(f"End Site OFFSET {a}", name)
                toks.expect("}")
            else:
                raise ClipError(f"line {toks.line()}: expected JOINT, End Site or '}}', found {tok!r}", path=path, joint=name)

    toks.expect("ROOT")
    joint(-1)
    if toks.peek() is not None:
        raise ClipError(f"line {toks.line()}: unexpected {toks.peek()!r} after the root joint (one ROOT per file)", path=path)

    lines = body.splitlines()
    n_head = head.count("\n")
    frames_m = re.match(r"\s*Frames:\s*(\S+)\s*$", lines[1] if len(lines) > 1 else "")
    time_m = re.match(r"\s*Frame\s+Time:\s*(\S+)\s*$", lines[2] if len(lines) > 2 else "")
    if not frames_m or not frames_m.group(1).isdigit():
        raise ClipError(f"line {n_head + 2}: expected 'Frames: <count>' after MOTION", path=path)
    try:
        frame_time = float(time_m.group(1)) if time_m else float("nan")
    except ValueError:
        frame_time = float("nan")
    if not (frame_time > 0 and np.isfinite(frame_time)):
        raise ClipError(f"line {n_head + 3}: expected 'Frame Time: <seconds > 0>'", path=path)
    n_frames = int(frames_m.group(1))
    total = sum(len(c) for c in channels)
    col_names = [f"{j}.{c}" for j, cs in zip(names, channels) for c in cs]
    data_lines = [ln for ln in lines[3:] if ln.strip()]
    if len(data_lines) < n_frames:
        raise ClipError(f"truncated: 'Frames: {n_frames}' but only {len(data_lines)} frame lines", path=path, frame=len(data_lines))
    if len(data_lines) > n_frames:
        raise ClipError(f"'Frames: {n_frames}' but {len(data_lines)} frame lines follow", path=path, frame=n_frames)
    if n_frames < 1:
        raise ClipError("no frames", path=path)
    motion = np.empty((n_frames, total))
    for k, ln in enumerate(data_lines):
        parts = ln.split()
        if len(parts) != total:
            raise ClipError(f"{len(parts)} values, expected {total} (one per channel of {len(names)} joints)", path=path, frame=k)
        try:
            motion[k] = np.array(parts, dtype=np.float64)
        except ValueError:
            bad = next(i for i, p in enumerate(parts) if not _is_float(p))
            raise ClipError(f"{parts[bad]!r} is not a number", path=path, frame=k, joint=col_names[bad]) from None
        if not np.all(np.isfinite(motion[k])):
            bad = int(np.flatnonzero(~np.isfinite(motion[k]))[0])
            raise ClipError(f"value {parts[bad]} is not finite", path=path, frame=k, joint=col_names[bad])
    return Bvh(str(path), tuple(names), tuple(parents), np.array(offsets), tuple(channels), frame_time, motion)


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False
