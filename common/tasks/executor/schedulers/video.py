"""Video: target frames from 3-D joint positions arriving over UDP (UniCon 2020, METHOD.md B
"Schedulers": "video: 3-D poses arrive over UDP, velocities interpolated from a short buffer").

    with VideoScheduler(model, dt_s, port=9870) as s:      # port 0: any free one, see s.port
        s.begin(rng)                                        # frames where the sender puts them
        ...  s.advance(rng, qpos); s.frame(1)               # drains the socket, never blocks

The packet (`pose_packet.py`, version 1): little-endian b"MMJP", version u8 = 1, J u8, flags
u16, frame index u32, timestamp f64 (s, the sender's stream clock), then J x 3 float32 joint
positions in metres (world frame, Z up) in the order of the model's bodies (for the humanoid:
root, chest, neck, right_shoulder, right_elbow, right_wrist, left_shoulder, left_elbow,
left_wrist, right_hip, right_knee, right_ankle, left_hip, left_knee, left_ankle); 20 + 12 J
bytes. `pose_sender.py` (`morphmimic send-poses`) sends clips in it.

Receiving: the socket is non-blocking and drained in `advance` (and `poll`), at most
`max_drain` datagrams a step, so the control loop never waits on the network and needs no
thread. Each accepted packet is turned into a pose by `PositionIK` (body origins -> qpos) and
kept with its timestamp in a buffer of the last `buffer_s` seconds.

Playback: the scheduler plays the buffer on its own clock, `delay_s` behind the newest packet,
so the lookahead frames (up to tau + 1 steps) and the velocities are interpolated between
received frames (slerp) rather than extrapolated. The clock advances one control step per
`advance` and is pulled gently (`sync_gain` per step) towards newest - delay, or snapped there
when more than `snap_s` off. When packets are late the clock runs past the newest frame and the
frames hold it (velocities go to zero); when they resume, it catches up. Velocities are centred
differences over +-1 control step of the interpolated buffer (`mj_differentiatePos`).

Bad input never raises out of the receive path: a packet that fails a check (`pose_packet.REASONS`),
comes out of order (a timestamp not after the newest, unless it starts a new stream: frame
index 0, or more than `restart_s` earlier; that clears the buffer), or makes the IK fail is counted in `rejected` (reason ->
count) with the message in `last_error`, and the scheduler keeps serving the last good frames.
Before the first packet it serves the model's rest pose (`qpos0`).

Placement: frames are where the sender says; `begin(..., align_to=qpos)` shifts them
horizontally so the root starts under the character (from the first packet if none yet). An
episode's reset resumes the clock (`restarts_on_reset` False): the character is put on the
frame playing now.
"""

from __future__ import annotations

import bisect
import socket
from collections import Counter
from typing import Any

import mujoco
import numpy as np

from common import udp_drops
from common.tasks.executor.schedulers import pose_packet
from common.tasks.executor.schedulers.pose_blend import PoseMath
from common.tasks.executor.schedulers.pose_ik import PositionIK
from common.tasks.executor.schedulers.base import TargetFrame

MAX_DATAGRAM = 65536
"""Bytes read per datagram: any UDP datagram fits, so an oversized one is seen whole and rejected."""


class VideoScheduler:
    """Target frames from joint positions received over UDP (UniCon 2020, METHOD.md B
    "Schedulers": video); see the module docstring.

    model: the character's model (an `ExecutorEnv`'s `ref_model`); dt_s: the control step;
    host/port: where to listen (127.0.0.1 by default; port 0 picks a free one, see `.port`).
    delay_s should cover the lookahead (tau + 1 steps and one more for the velocity) so those
    frames are interpolated, and buffer_s the lookback (`make_scheduler` sees to both).
    """

    restarts_on_reset = False
    """A reset resumes the playback clock where it is (the character is put on the frame now)."""

    def __init__(self, model: mujoco.MjModel, dt_s: float, *, host: str = "127.0.0.1", port: int = 0,
                 delay_s: float = 0.1, buffer_s: float = 2.0, sync_gain: float = 0.1, snap_s: float = 0.5,
                 restart_s: float = 1.0, max_drain: int = 256):
        if not (0.0 <= delay_s <= 5.0 and 0.1 <= buffer_s <= 60.0 and delay_s < buffer_s):
            raise ValueError(f"delay_s {delay_s} must be in [0, 5] and below buffer_s {buffer_s} (in [0.1, 60])")
        if not 0 <= int(port) <= 65535:
            raise ValueError(f"port {port} must be in 0 .. 65535")
        self.model = model
        self.pm = PoseMath(model)
        self.ik = PositionIK(model)
        self.joints = pose_packet.joint_names(model)
        self.dt = float(dt_s)
        self.delay_s, self.buffer_s = float(delay_s), float(buffer_s)
        self.sync_gain, self.snap_s, self.restart_s = float(sync_gain), float(snap_s), float(restart_s)
        self.max_drain = int(max_drain)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setblocking(False)
            self.sock.bind((host, int(port)))
        except OSError:
            self.sock.close()
            raise
        self.host, self.port = self.sock.getsockname()[0], int(self.sock.getsockname()[1])
        self.received = 0
        """Packets accepted since construction."""
        self.kernel_dropped = 0
        """Datagrams the kernel dropped before `recv` (a full receive buffer), as of the last
        `status()` or `poll` that found the socket's buffer full (`common.udp_drops`)."""
        self.rejected: Counter[str] = Counter()
        """Packets rejected since construction, by reason (pose_packet.REASONS, out_of_order, ik, socket)."""
        self.last_error = ""
        self.restarts = 0
        self.clip_id = "video"
        self.k = 0
        self._times: list[float] = []
        self._frames: list[np.ndarray] = []
        self._last_index = -1
        self._clock = 0.0
        self._shift = np.zeros(2)
        self._pending_align: np.ndarray | None = None
        self._rest = model.qpos0.copy()
        self._cache: dict[float, np.ndarray] = {}

    # ---- lifetime ----

    def close(self) -> None:
        """Close the socket (idempotent); the scheduler keeps serving what it has."""
        if self.sock.fileno() >= 0:
            self.dropped()  # NOTE: the count goes with the socket: keep its last value
            self.sock.close()

    def dropped(self) -> int:
        """Datagrams the kernel dropped on this socket so far (0 where the system does not say)."""
        n = udp_drops.kernel_drops(self.sock)
        if n is not None:
            self.kernel_dropped = max(self.kernel_dropped, n)
        return self.kernel_dropped

    @property
    def closed(self) -> bool:
        return self.sock.fileno() < 0

    def __enter__(self) -> "VideoScheduler":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ---- receiving ----

    def poll(self) -> int:
        """Drain the socket without blocking (at most `max_drain` datagrams); returns how many
        were accepted. Never raises: failures are counted in `rejected`."""
        if self.closed:
            return 0
        accepted = 0
        for _ in range(self.max_drain):
            try:
                data = self.sock.recv(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:  # NOTE: e.g. an ICMP error queued on the socket; the next recv goes on
                self._reject("socket", f"recv failed: {exc}")
                continue
            accepted += self.accept(data)
        return accepted

    def accept(self, data: bytes) -> int:
        """Take one datagram (what `poll` does with each); 1 if accepted, 0 if rejected."""
        try:
            packet = pose_packet.decode(data, len(self.joints))
        except pose_packet.PacketError as exc:
            self._reject(exc.reason, str(exc))
            return 0
        except Exception as exc:  # NOTE: never let a packet break the control loop
            self._reject("error", f"{type(exc).__name__}: {exc}")
            return 0
        t = packet.timestamp_s
        if self._times and t <= self._times[-1]:
            if t < self._times[-1] - self.restart_s or packet.frame_index == 0:
                self.restarts += 1
                self._times, self._frames = [], []
            else:
                self._reject("out_of_order", f"frame {packet.frame_index} at {t:.3f} s is not after the newest ({self._times[-1]:.3f} s)")
                return 0
        try:
            qpos = self.ik.solve(packet.positions)
        except Exception as exc:
            self._reject("ik", f"IK failed: {type(exc).__name__}: {exc}")
            return 0
        if not np.all(np.isfinite(qpos)):
            self._reject("ik", "IK gave a non-finite pose (coincident joints?)")
            return 0
        self._times.append(t)
        self._frames.append(qpos)
        self._cache.clear()
        self._last_index = packet.frame_index
        self.received += 1
        cut = bisect.bisect_left(self._times, t - self.buffer_s)
        if cut > 0 and len(self._times) - cut >= 2:
            del self._times[:cut], self._frames[:cut]
        if self._pending_align is not None:
            self._shift = self._pending_align - qpos[0:2]
            self._pending_align = None
        if len(self._times) == 1:
            self._clock = t - self.delay_s
        return 1

    def _reject(self, reason: str, message: str) -> None:
        self.rejected[reason] += 1
        self.last_error = f"{reason}: {message}"

    # ---- the Scheduler contract ----

    def begin(self, rng: np.random.Generator, clip_id: str | None = None, start_s: float | None = None,
              align_to: np.ndarray | None = None) -> None:
        """Start playing what arrives (clip_id and start_s do not apply to a live source):
        the clock snaps to newest - delay; with `align_to` (a qpos) the frames are shifted so
        the root is under it now (or at the first packet)."""
        self.poll()
        self.k = 0
        self._cache.clear()
        if self._times:
            self._clock = self._times[-1] - self.delay_s
        self._shift = np.zeros(2)
        self._pending_align = None
        if align_to is not None:
            target = np.asarray(align_to[0:2], dtype=np.float64).copy()
            if self._times:
                self._shift = target - self._sample(self._clock)[0:2]
            else:
                self._pending_align = target
                self._shift = target - self._rest[0:2]

    def frame(self, i: int) -> TargetFrame:
        t = self._clock + int(i) * self.dt
        a, q, b = self._placed(t - self.dt), self._placed(t), self._placed(t + self.dt)
        return TargetFrame(q, self.pm.velocity(a, b, 2.0 * self.dt))

    def advance(self, rng: np.random.Generator, qpos: np.ndarray) -> bool:
        """Drain the socket and move the clock one step (module docstring). False: a live source
        is followed as it moves (a stream restart included)."""
        self.poll()
        self.k += 1
        self._clock += self.dt
        if self._times:
            err = (self._times[-1] - self.delay_s) - self._clock
            self._clock += err if abs(err) > self.snap_s else self.sync_gain * err
        self._cache.clear()
        return False

    @property
    def done(self) -> bool:
        return False

    @property
    def late(self) -> bool:
        """The clock has run past the newest frame: the frames hold it."""
        return not self._times or self._clock > self._times[-1]

    def status(self) -> dict:
        """clip_time_s is the playback clock (stream time); behind_s how far it is behind the
        newest packet (None before any); dropped the datagrams the kernel dropped (`dropped()`). No NaN, so the dict serializes to strict JSON."""
        return {"clip_id": self.clip_id, "clip_time_s": float(self._clock), "clip_duration_s": 0.0, "steps_left": 0,
                "received": self.received, "rejected": int(sum(self.rejected.values())), "dropped": self.dropped(),
                "buffered": len(self._times),
                "behind_s": float(self._times[-1] - self._clock) if self._times else None, "late": self.late,
                "last_error": self.last_error}

    # ---- the buffer ----

    def sample(self, t_s: float) -> TargetFrame:
        """The frame at stream time `t_s` (s, the sender's clock), placed (shifted): interpolated
        between received frames, held beyond the buffer's ends."""
        a, q, b = self._placed(t_s - self.dt), self._placed(t_s), self._placed(t_s + self.dt)
        return TargetFrame(q, self.pm.velocity(a, b, 2.0 * self.dt))

    @property
    def times(self) -> np.ndarray:
        """Stream times (s) of the buffered frames."""
        return np.array(self._times)

    def _placed(self, t: float) -> np.ndarray:
        key = round(t, 9)
        q = self._cache.get(key)
        if q is None:
            q = self._sample(t).copy()
            q[0:2] += self._shift
            self._cache[key] = q
        return q

    def _sample(self, t: float) -> np.ndarray:
        """Buffer interpolated at t, unshifted (the rest pose when empty)."""
        times = self._times
        if not times:
            return self._rest
        if t <= times[0]:
            return self._frames[0]
        if t >= times[-1]:
            return self._frames[-1]
        r = bisect.bisect_right(times, t)
        t0, t1 = times[r - 1], times[r]
        return self.pm.blend(self._frames[r - 1], self._frames[r], (t - t0) / (t1 - t0))
