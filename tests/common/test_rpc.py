"""`RouterServer` answers every peer without ever waiting on one: a peer that sends requests and
never reads its replies loses them (counted), and the server goes on answering the others
(real ZeroMQ sockets on 127.0.0.1, with and without CURVE)."""

from __future__ import annotations

import threading
import time

import pytest
import zmq

from common import curve_keys, rpc, sockets, wire
from common.curve_keys import LEARNER, RunKeys


def _draw_request() -> wire.DrawRequestMsg:
    return wire.DrawRequestMsg(n=4)


def _big_reply(request):
    # a reply large enough that an unread pipe fills within a few hundred requests
    return wire.StatsReplyMsg(stats={f"k{i}": float(i) for i in range(2000)})


@pytest.mark.parametrize("curve", [False, True])
def test_a_peer_that_never_reads_cannot_block_the_server(curve) -> None:
    keys = RunKeys.generate() if curve else None
    sock, endpoint = sockets.bind_router("tcp://127.0.0.1", keys)
    server = rpc.RouterServer(sock, _big_reply, "test")
    stop = threading.Event()
    served_after = []

    def serve() -> None:
        while not stop.is_set():
            server.serve_pending(timeout_ms=10)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        silent = sockets.context().socket(zmq.DEALER)  # a peer that keeps at most one reply and reads none
        curve_keys.make_client(silent, keys, LEARNER)
        silent.setsockopt(zmq.RCVHWM, 1)
        silent.setsockopt(zmq.RCVBUF, 4096)
        silent.connect(endpoint)
        frames = wire.encode(_draw_request())
        for _ in range(3000):  # bounded: far more replies than the pipes hold
            silent.send_multipart([b"", *frames], copy=False)
        deadline = time.monotonic() + 30.0
        while server.served + sum(server.dropped.values()) < 3000 and time.monotonic() < deadline:
            time.sleep(0.05)  # the server works through the silent peer's requests
        client = rpc.RpcClient(endpoint, timeout_s=5.0, retries=2, keys=keys, role=LEARNER)
        for _ in range(5):
            served_after.append(client.call(_draw_request(), wire.StatsReplyMsg))
        client.close()
        silent.close(linger=0)
    finally:
        stop.set()
        thread.join(timeout=10)
        server.close()
    assert not thread.is_alive(), "the server thread is stuck in a send"
    assert len(served_after) == 5
    assert server.dropped["full_pipe"] >= 1, (server.served, dict(server.dropped))
    assert server.dropped["full_pipe"] + server.dropped["over_backlog"] + server.served >= 3000
    assert server.dropped["full_pipe"] <= rpc.MAX_BACKLOG + 3000 // rpc.MAX_BACKLOG + 1  # bounded work for a silent peer
