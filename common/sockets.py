"""Every ZeroMQ socket of the system is made here, with its high-water mark, LINGER and what
it loses when a limit is hit written beside the option.

Every function takes the run's CURVE keys (`common.curve_keys.RunKeys`; None: no
authentication, for tests of the codec alone and `--no-curve`): a bound socket becomes a CURVE
server that admits only this run's clients, a connecting one a client in its role
(`curve_keys.ACTOR` or `curve_keys.LEARNER`).

Patterns (DESIGN.md "Data flows"):
    unrolls   actor PUSH  -> learner PULL (learner binds)
    weights   learner PUB -> actor SUB, plus a snapshot request DEALER -> learner ROUTER
    sampler   client DEALER -> sampler ROUTER (sampler binds; Lazy Pirate retries in the client)
"""

from __future__ import annotations

import zmq

from common import curve_keys
from common.curve_keys import ACTOR, RunKeys

UNROLL_SEND_HWM = 4
"""Unrolls an actor may queue before `send` blocks: backpressure slows collection, loses nothing."""
UNROLL_RECV_HWM = 4
"""Unrolls the learner's PULL buffers per peer; beyond it the peer's PUSH blocks (no loss).
Small on purpose: on-policy PPO wants fresh data, so a busy learner should pause the actors
(backpressure) rather than let a backlog of soon-stale unrolls pile up."""
WEIGHTS_HWM = 2
"""PUB/SUB keep at most 2 weight messages; an older one is dropped, the newest is all that matters."""
ROUTER_HWM = 1000
"""Requests/replies queued per peer; with ROUTER_MANDATORY a full or gone peer raises instead of a silent drop."""
LINGER_MS = 0
"""On close, pending outgoing messages are discarded at once: shutdown never hangs on a dead peer.
Unrolls are not lost uncounted at shutdown: the learner drains its PULL until each actor's final
heartbeat before the actors close (`LearnerTransport.drain`), and that heartbeat's sequence number
counts whatever did not arrive."""


def context() -> zmq.Context:
    """The process-wide context (one I/O thread is plenty for our message rates)."""
    return zmq.Context.instance()


def endpoint(host: str, port: int) -> str:
    return f"tcp://{host}:{port}"


def _bind(sock: zmq.Socket, address: str) -> str:
    """Bind to `address`; a `tcp://host` without port picks a free one. Returns the endpoint."""
    if address.startswith("tcp://") and address.count(":") == 1:
        port = sock.bind_to_random_port(address)
        return f"{address}:{port}"
    sock.bind(address)
    return sock.getsockopt_string(zmq.LAST_ENDPOINT)


UNROLL_MAX_BYTES = 256 * 1024 * 1024
"""Largest unroll-channel message the learner takes. libzmq drops the connection of a peer that
sends more: the message is lost, counted only as that connection's end (`common.socket_events`)."""


def bind_unroll_pull(address: str, keys: RunKeys | None = None,
                     max_msg_bytes: int = UNROLL_MAX_BYTES) -> tuple[zmq.Socket, str]:
    """Learner side of the unroll stream."""
    if not 1 <= max_msg_bytes <= UNROLL_MAX_BYTES:
        raise ValueError(f"max_msg_bytes = {max_msg_bytes}; allowed: 1 .. {UNROLL_MAX_BYTES}")
    sock = context().socket(zmq.PULL)
    curve_keys.make_server(sock, keys)
    sock.setsockopt(zmq.RCVHWM, UNROLL_RECV_HWM)
    sock.setsockopt(zmq.MAXMSGSIZE, max_msg_bytes)  # a larger frame drops that peer's connection
    sock.setsockopt(zmq.LINGER, LINGER_MS)
    return sock, _bind(sock, address)


def connect_unroll_push(endpoint_: str, keys: RunKeys | None = None) -> zmq.Socket:
    """Actor side of the unroll stream. `send` blocks when the learner falls behind (backpressure);
    callers use a send timeout so a vanished learner cannot hang an actor forever."""
    sock = context().socket(zmq.PUSH)
    curve_keys.make_client(sock, keys, ACTOR)
    sock.setsockopt(zmq.SNDHWM, UNROLL_SEND_HWM)
    sock.setsockopt(zmq.LINGER, LINGER_MS)
    sock.setsockopt(zmq.SNDTIMEO, 5000)  # a blocked send raises zmq.Again after 5 s: counted, retried
    sock.setsockopt(zmq.IMMEDIATE, 1)  # queue only to a completed connection: nothing parked on a dead pipe
    sock.connect(endpoint_)
    return sock


def bind_weights_pub(address: str, keys: RunKeys | None = None) -> tuple[zmq.Socket, str]:
    """Learner publishes weights; slow joiners miss messages, hence the snapshot ROUTER."""
    sock = context().socket(zmq.PUB)
    curve_keys.make_server(sock, keys)
    sock.setsockopt(zmq.SNDHWM, WEIGHTS_HWM)
    sock.setsockopt(zmq.LINGER, LINGER_MS)
    return sock, _bind(sock, address)


def connect_weights_sub(endpoint_: str, keys: RunKeys | None = None) -> zmq.Socket:
    sock = context().socket(zmq.SUB)
    curve_keys.make_client(sock, keys, ACTOR)
    sock.setsockopt(zmq.RCVHWM, WEIGHTS_HWM)
    sock.setsockopt(zmq.LINGER, LINGER_MS)
    sock.setsockopt(zmq.SUBSCRIBE, b"")
    sock.connect(endpoint_)
    return sock


def bind_router(address: str, keys: RunKeys | None = None) -> tuple[zmq.Socket, str]:
    """A request/reply service (the learner's weight snapshots, the sampler)."""
    sock = context().socket(zmq.ROUTER)
    curve_keys.make_server(sock, keys)
    sock.setsockopt(zmq.ROUTER_MANDATORY, 1)  # reply to a vanished peer raises EHOSTUNREACH instead of vanishing
    sock.setsockopt(zmq.SNDHWM, ROUTER_HWM)
    sock.setsockopt(zmq.RCVHWM, ROUTER_HWM)
    sock.setsockopt(zmq.LINGER, LINGER_MS)
    sock.setsockopt(zmq.MAXMSGSIZE, 64 * 1024 * 1024)  # a peer sending more is disconnected by libzmq
    return sock, _bind(sock, address)


def connect_dealer(endpoint_: str, keys: RunKeys | None = None, role: str = ACTOR) -> zmq.Socket:
    """A client of a ROUTER service, in `role`. Lazy Pirate: on a reply timeout the caller
    closes this socket and makes a new one, so a lost request or a restarted service cannot
    wedge it."""
    sock = context().socket(zmq.DEALER)
    curve_keys.make_client(sock, keys, role)
    sock.setsockopt(zmq.SNDHWM, ROUTER_HWM)
    sock.setsockopt(zmq.RCVHWM, ROUTER_HWM)
    sock.setsockopt(zmq.LINGER, LINGER_MS)
    sock.connect(endpoint_)
    return sock
