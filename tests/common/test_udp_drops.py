"""Datagrams the kernel drops on a full receive buffer are counted (issue 54, item 4): on a
plain socket and on the live pose receiver (the video scheduler), over real UDP on 127.0.0.1,
every datagram sent is either read or counted as dropped."""

from __future__ import annotations

import socket
import sys

import numpy as np
import pytest

from common import udp_drops
from common.tasks.base import TaskConfig
from common.tasks.body_config import BodyConfig
from common.tasks.executor.config import ExecutorConfig
from common.tasks.executor.schedulers import pose_packet
from common.tasks.executor.schedulers.video import VideoScheduler
from common.tasks.registry import make_env

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the drop count comes from Linux's /proc")
SENT = 1500


def _drain(sock: socket.socket) -> int:
    n = 0
    while True:
        try:
            sock.recv(65536)
        except BlockingIOError:
            return n
        n += 1


def test_a_burst_into_a_small_buffer_is_read_or_counted_dropped():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8192)
        rx.bind(("127.0.0.1", 0))
        rx.setblocking(False)
        assert udp_drops.kernel_drops(rx) == 0
        for _ in range(SENT):
            tx.sendto(b"x" * 200, rx.getsockname())
        read = _drain(rx)
        dropped = udp_drops.kernel_drops(rx)
    assert dropped > 0 and read + dropped == SENT, (read, dropped)
    assert udp_drops.kernel_drops(rx) is None  # closed: the system no longer says


def test_the_live_pose_receiver_shows_what_the_kernel_dropped():
    from learner.live.session import video_status

    cfg = TaskConfig(name="executor", control_hz=60.0, sim_hz=240.0, episode_s=5.0,
                     body=BodyConfig(parameterization="height_thickness", vary_shape=False), executor=ExecutorConfig())
    env = make_env(cfg, seed=0)
    rx = VideoScheduler(env.ref_model, 1 / 60)
    joints = len(rx.joints)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for k in range(SENT):  # made-up positions: accepted or rejected by IK, either way read
                positions = np.array([[0.0, 0.0, 1.0 + 0.01 * j] for j in range(joints)])
                tx.sendto(pose_packet.encode(k, k / 60, positions), ("127.0.0.1", rx.port))
        for _ in range(SENT):  # each poll reads up to max_drain; stop once one reads nothing
            before = rx.received + sum(rx.rejected.values())
            rx.poll()
            if rx.received + sum(rx.rejected.values()) == before:
                break
        status = rx.status()
        line = video_status(rx)
    finally:
        rx.close()
    read = rx.received + sum(rx.rejected.values())
    assert status["dropped"] > 0 and read + status["dropped"] == SENT, (read, status)
    assert f"dropped by the kernel {status['dropped']}" in line
    assert rx.dropped() == status["dropped"]  # kept after close
