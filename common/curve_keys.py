"""Only members get in: CURVE keys made per run, and the ZAP handler that checks them.

Every ZeroMQ socket of a run is authenticated and encrypted with CURVE (libzmq's
CurveZMQ: Curve25519 keys, each connection's traffic encrypted with its own session key).
`RunKeys.generate()` makes, for one run, a server key pair (every socket that binds: the
learner's unroll PULL, weights PUB and snapshot ROUTER, the sampler's ROUTER) and two client
key pairs, one for the learner's own client sockets and one for the rollout actors. The learner
hands each part only what it needs, through Ray's actor arguments (never a file, never a socket
of ours):

- actors: the server's public key and the actor key pair (`RunKeys.for_actors`);
- the sampler: the server key pair and the two clients' public keys (`RunKeys.for_sampler`).

A server socket's process runs one `Gatekeeper` (a ZAP handler, pyzmq's `ThreadAuthenticator`)
per ZeroMQ context: it admits the two client public keys and stamps each connection's messages
with a `User-Id` naming the role (`learner` or `actor`), which the sampler reads to take
state-changing requests from the learner only. A peer without a key (a plain connection), with
another run's key or a made-up one fails the handshake; `RefusalCounter` counts those from the
server socket's monitor events, so every refusal shows up in the run's counters.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace

import zmq
from zmq.auth.thread import ThreadAuthenticator
from zmq.utils import z85
from zmq.utils.monitor import recv_monitor_message

LEARNER, ACTOR = "learner", "actor"
"""The roles a client key stands for (the `User-Id` the Gatekeeper gives its connections)."""

REFUSAL_EVENTS = {
    zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL: "auth_protocol",
    zmq.EVENT_HANDSHAKE_FAILED_AUTH: "auth_denied",
    zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL: "auth_failed",
}
"""Monitor events that mean a peer was refused, by the counter they go to: a peer that speaks no
CURVE (or garbage), a key the Gatekeeper does not know, a handshake that broke off."""


@dataclass(frozen=True)
class RunKeys:
    """CURVE keys of one run, z85-encoded bytes. A part that must not hold a secret gets a copy
    with it blanked (`b""`)."""

    server_public: bytes
    server_secret: bytes
    learner_public: bytes
    learner_secret: bytes
    actor_public: bytes
    actor_secret: bytes

    @staticmethod
    def generate() -> "RunKeys":
        server, learner, actor = zmq.curve_keypair(), zmq.curve_keypair(), zmq.curve_keypair()
        return RunKeys(*server, *learner, *actor)

    def for_actors(self) -> "RunKeys":
        """What a rollout actor holds: the server's public key and its own key pair."""
        return replace(self, server_secret=b"", learner_secret=b"")

    def for_sampler(self) -> "RunKeys":
        """What the sampler service holds: the server key pair and the clients' public keys."""
        return replace(self, learner_secret=b"", actor_secret=b"")

    def client_pair(self, role: str) -> tuple[bytes, bytes]:
        pair = {LEARNER: (self.learner_public, self.learner_secret), ACTOR: (self.actor_public, self.actor_secret)}[role]
        if not pair[1]:
            raise ValueError(f"these keys hold no {role} secret key")
        return pair

    def roles(self) -> dict[bytes, str]:
        """Client public key -> role."""
        return {self.learner_public: LEARNER, self.actor_public: ACTOR}


def make_server(sock: zmq.Socket, keys: RunKeys | None) -> None:
    """Make `sock` (before it binds) a CURVE server of this run; no-op without keys."""
    if keys is None:
        return
    if not keys.server_secret:
        raise ValueError("these keys hold no server secret key: only the learner and the sampler bind")
    Gatekeeper.serve(sock.context, keys)
    sock.curve_secretkey = keys.server_secret
    sock.curve_publickey = keys.server_public
    sock.curve_server = True


def make_client(sock: zmq.Socket, keys: RunKeys | None, role: str) -> None:
    """Make `sock` (before it connects) a CURVE client of this run in `role`; no-op without keys."""
    if keys is None:
        return
    public, secret = keys.client_pair(role)
    sock.curve_serverkey = keys.server_public
    sock.curve_publickey = public
    sock.curve_secretkey = secret


def role_of(frame: zmq.Frame) -> str:
    """The role of the connection a received frame came from (`learner`, `actor`), or "" on a
    socket without CURVE."""
    try:
        return frame.get("User-Id") or ""
    except zmq.ZMQError:  # NOTE: no User-Id property when the connection had no ZAP handshake
        return ""


class Gatekeeper(ThreadAuthenticator):
    """The ZAP handler of one ZeroMQ context: admits this run's client keys, names their role."""

    _by_context: dict[int, "Gatekeeper"] = {}
    _lock = threading.Lock()

    def __init__(self, context: zmq.Context, keys: RunKeys):
        super().__init__(context)
        self.keys_by_z85 = keys.roles()
        self.denied = 0

    @classmethod
    def serve(cls, context: zmq.Context, keys: RunKeys) -> "Gatekeeper":
        """The context's running Gatekeeper, started on first use. A context serves one run's
        keys at a time; a new run's keys (a test's second run in one process) are added."""
        with cls._lock:
            gate = cls._by_context.get(id(context))
            if gate is None or gate.context.closed:
                gate = cls(context, keys)
                gate.start()
                gate.configure_curve_callback("*", credentials_provider=gate)
                cls._by_context[id(context)] = gate
            else:
                gate.keys_by_z85.update(keys.roles())
            return gate

    def callback(self, domain: str, key: bytes) -> bool:
        """pyzmq's credentials-provider hook: is this z85 client key one of ours?"""
        ok = key in self.keys_by_z85
        self.denied += not ok
        return ok

    def curve_user_id(self, client_public_key: bytes) -> str:
        return self.keys_by_z85.get(z85.encode(client_public_key), "")


class RefusalCounter:
    """Counts refused peers on one server socket from its monitor events (non-blocking `poll`)."""

    def __init__(self, sock: zmq.Socket):
        events = 0
        for event in REFUSAL_EVENTS:
            events |= event
        self._monitor = sock.get_monitor_socket(events)

    def poll(self, counters, prefix: str = "") -> int:
        """Add the refusals seen since the last call to `counters` (a Counter) under
        `prefix + kind`; returns how many."""
        n = 0
        while True:
            try:
                event = recv_monitor_message(self._monitor, flags=zmq.NOBLOCK)
            except zmq.Again:
                return n
            except zmq.ZMQError:
                return n
            kind = REFUSAL_EVENTS.get(event["event"])
            if kind:
                counters[prefix + kind] += 1
                n += 1

    def close(self) -> None:
        self._monitor.close(linger=0)
