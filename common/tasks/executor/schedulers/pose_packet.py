"""The UDP packet of 3-D joint positions the video scheduler receives (UniCon 2020, METHOD.md B
"Schedulers": "video: 3-D poses arrive over UDP"), version 1.

One datagram carries one frame of J joint positions, all little-endian, no padding:

    offset  size    type      field
    0       4       bytes     magic b"MMJP" (MorphMimic Joint Positions)
    4       1       uint8     version: 1
    5       1       uint8     J, the number of joints (1 .. 255; must be the receiver's count)
    6       2       uint16    flags: 0 (reserved; receivers ignore them)
    8       4       uint32    frame index: the sender's counter from 0 (0 starts a new stream)
    12      8       float64   timestamp: seconds on the sender's stream clock, increasing within a
                              stream (the receiver only uses differences; a jump back by more
                              than a second also starts a new stream)
    20      12 J    float32   J x (x, y, z): joint positions in metres, world frame, Z up

So a packet is 20 + 12 J bytes (200 for the humanoid's 15) and never more than
`MAX_PACKET_BYTES` (20 + 12 x 255 = 3080). The joints are the character's bodies in model
order, world excluded: each body's origin, which is its joint's centre (`joint_names(model)`).
For the DeepMimic humanoid (`HUMANOID_JOINTS`): root (the pelvis, where the free joint sits),
chest, neck, right_shoulder, right_elbow, right_wrist, left_shoulder, left_elbow, left_wrist,
right_hip, right_knee, right_ankle, left_hip, left_knee, left_ankle.

`decode` rejects a packet with a `PacketError` whose `reason` names the check that failed
(`REASONS`); the receiver counts them by reason.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import mujoco
import numpy as np

MAGIC = b"MMJP"
VERSION = 1
HEADER = struct.Struct("<4sBBHId")
"""magic, version, n_joints, flags, frame index, timestamp: 20 bytes."""
MAX_JOINTS = 255
MAX_PACKET_BYTES = HEADER.size + 12 * MAX_JOINTS
MAX_ABS_POSITION_M = 1.0e4
"""Positions farther than this from the origin are rejected (garbage that happens to be finite)."""
HUMANOID_JOINTS = ("root", "chest", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder", "left_elbow",
                   "left_wrist", "right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle")
REASONS = ("short", "oversized", "magic", "version", "joint_count", "size", "non_finite", "out_of_range")
"""Why `decode` rejects a packet: shorter than the header; longer than MAX_PACKET_BYTES; wrong
magic; unknown version; J is not the receiver's joint count; length is not 20 + 12 J; a NaN or
inf position or timestamp; a position beyond MAX_ABS_POSITION_M."""


class PacketError(ValueError):
    """A rejected packet; `reason` is one of `REASONS`."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class PosePacket:
    """A decoded packet: frame index, timestamp (s), positions `[J, 3]` float64 metres."""

    frame_index: int
    timestamp_s: float
    positions: np.ndarray


def joint_names(model: mujoco.MjModel) -> tuple[str, ...]:
    """The joints a packet carries for `model`: its bodies in model order, world excluded."""
    return tuple(model.body(b).name for b in range(1, model.nbody))


def encode(frame_index: int, timestamp_s: float, positions: np.ndarray) -> bytes:
    """One packet of positions `[J, 3]` (metres) at `timestamp_s`; see the module docstring."""
    p = np.asarray(positions, dtype="<f4")
    if p.ndim != 2 or p.shape[1] != 3 or not 1 <= p.shape[0] <= MAX_JOINTS:
        raise ValueError(f"positions must be [J, 3] with 1 <= J <= {MAX_JOINTS}, not {p.shape}")
    return HEADER.pack(MAGIC, VERSION, p.shape[0], 0, int(frame_index) & 0xFFFFFFFF, float(timestamp_s)) + p.tobytes()


def decode(data: bytes, n_joints: int) -> PosePacket:
    """Check and decode one packet for a receiver expecting `n_joints`; raises PacketError."""
    n = len(data)
    if n < HEADER.size:
        raise PacketError("short", f"packet of {n} bytes is shorter than the {HEADER.size}-byte header")
    if n > MAX_PACKET_BYTES:
        raise PacketError("oversized", f"packet of {n} bytes is over the {MAX_PACKET_BYTES}-byte limit")
    magic, version, joints, _flags, index, stamp = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise PacketError("magic", f"magic {magic!r} is not {MAGIC!r}")
    if version != VERSION:
        raise PacketError("version", f"version {version} is not {VERSION}")
    if joints != n_joints:
        raise PacketError("joint_count", f"packet has {joints} joints, this receiver expects {n_joints}")
    if n != HEADER.size + 12 * joints:
        raise PacketError("size", f"packet of {n} bytes: {joints} joints need {HEADER.size + 12 * joints}")
    p = np.frombuffer(data, dtype="<f4", count=3 * joints, offset=HEADER.size).reshape(joints, 3).astype(np.float64)
    if not (math.isfinite(stamp) and np.all(np.isfinite(p))):
        raise PacketError("non_finite", "NaN or inf in the timestamp or positions")
    if np.max(np.abs(p)) > MAX_ABS_POSITION_M:
        raise PacketError("out_of_range", f"a position is farther than {MAX_ABS_POSITION_M:g} m from the origin")
    return PosePacket(int(index), float(stamp), p)
