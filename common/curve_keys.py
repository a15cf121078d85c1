"""Only members get in: CURVE keys made per run, and the ZAP handler that checks them.

Every ZeroMQ socket of a run is authenticated and encrypted with CURVE (libzmq's
CurveZMQ: Curve25519 keys, each connection's traffic encrypted with its own session key).
`RunKeys.generate(num_actors)` makes, for one run, a server key pair (every socket that binds:
the learner's unroll PULL, weights PUB and snapshot ROUTER, the sampler's ROUTER) and client key
pairs: one for the learner's own client sockets and one per rollout actor. The learner hands each
part only what it needs, through Ray's actor arguments (never a file, never a socket of ours):

- actor i: the server's public key and actor i's key pair (`RunKeys.for_actor`);
- the sampler: the server key pair and the clients' public keys (`RunKeys.for_sampler`).

A server socket's process runs one `Gatekeeper` (a ZAP handler, pyzmq's `ThreadAuthenticator`)
per ZeroMQ context: it admits the client public keys and stamps each connection's messages with
a `User-Id` naming who holds the key (`learner`, or `actor/<id>`): the sampler reads it to take
state-changing requests from the learner only, and the learner to take an actor's unrolls and
heartbeats only under that actor's own key (`actor_user_id`), so one actor's key cannot speak
for another actor id. A peer without a key (a plain connection), with
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
"""The roles a client key stands for: the learner's `User-Id` is its role; an actor's is
`actor_user_id(its id)`."""

REFUSAL_EVENTS = {
    zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL: "auth_protocol",
    zmq.EVENT_HANDSHAKE_FAILED_AUTH: "auth_denied",
    zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL: "auth_failed",
}
"""Monitor events that mean a peer was refused, by the counter they go to: a peer that speaks no
CURVE (or garbage), a key the Gatekeeper does not know, a handshake that broke off."""


def actor_user_id(actor_id: int) -> str:
    """The `User-Id` of actor `actor_id`'s connections: what the learner compares with the actor
    id a message claims."""
    return f"{ACTOR}/{actor_id}"


@dataclass(frozen=True)
class RunKeys:
    """CURVE keys of one run, z85-encoded bytes. A part that must not hold a secret gets a copy
    with it blanked (`b""`)."""

    server_public: bytes
    server_secret: bytes
    learner_public: bytes
    learner_secret: bytes
    actor_public: bytes
    """The actor key pair this copy speaks with: actor `actor_id`'s."""
    actor_secret: bytes
    actor_id: int = 0
    actor_keys: tuple[tuple[bytes, bytes], ...] = ()
    """Every actor's (public, secret) pair by actor id: all of them in the learner's copy, the
    public keys only in the sampler's, none in an actor's."""

    @staticmethod
    def generate(num_actors: int = 1) -> "RunKeys":
        """A server pair, the learner's pair and one pair per actor id 0..num_actors-1."""
        if not 1 <= num_actors <= 2**16:
            raise ValueError(f"num_actors = {num_actors}; allowed: [1, {2**16}]")
        server, learner = zmq.curve_keypair(), zmq.curve_keypair()
        actors = tuple(zmq.curve_keypair() for _ in range(num_actors))
        return RunKeys(*server, *learner, *actors[0], actor_id=0, actor_keys=actors)

    def for_actor(self, actor_id: int) -> "RunKeys":
        """What rollout actor `actor_id` holds: the server's public key and its own key pair."""
        if not any(secret for _, secret in self.actor_keys):
            raise ValueError("these keys hold no actor's secret key: only the learner's copy hands them out")
        if not 0 <= actor_id < len(self.actor_keys):
            raise ValueError(f"actor id {actor_id}: these keys are for actors 0..{len(self.actor_keys) - 1}")
        public, secret = self.actor_keys[actor_id]
        return replace(self, server_secret=b"", learner_secret=b"", actor_public=public, actor_secret=secret,
                       actor_id=actor_id, actor_keys=())

    def for_actors(self) -> "RunKeys":
        """Actor 0's keys (`for_actor(0)`): for tools that stand in for one actor."""
        return self.for_actor(0)

    def for_sampler(self) -> "RunKeys":
        """What the sampler service holds: the server key pair and the clients' public keys."""
        return replace(self, learner_secret=b"", actor_secret=b"", actor_keys=tuple((p, b"") for p, _ in self.actor_keys))

    def client_pair(self, role: str) -> tuple[bytes, bytes]:
        pair = {LEARNER: (self.learner_public, self.learner_secret), ACTOR: (self.actor_public, self.actor_secret)}[role]
        if not pair[1]:
            raise ValueError(f"these keys hold no {role} secret key")
        return pair

    def roles(self) -> dict[bytes, str]:
        """Client public key -> `User-Id`: `learner`, or `actor/<id>` for each actor's key."""
        out = {self.actor_public: actor_user_id(self.actor_id)}
        out.update((public, actor_user_id(i)) for i, (public, _) in enumerate(self.actor_keys))
        out[self.learner_public] = LEARNER
        return out


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
    """The `User-Id` of the connection a received frame came from (`learner`, `actor/<id>`), or
    "" on a socket without CURVE."""
    try:
        return frame.get("User-Id") or ""
    except zmq.ZMQError:  # NOTE: no User-Id property when the connection had no ZAP handshake
        return ""


class Gatekeeper(ThreadAuthenticator):
    """The ZAP handler of one ZeroMQ context: admits this run's client keys, names who holds each."""

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
        self._sock = sock
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
        """Stop monitoring, then close the monitor's end (as `socket_events.ConnectionEvents`: a
        socket closed with its monitor still on left later sockets of the process deaf)."""
        if not self._sock.closed:
            self._sock.disable_monitor()
        self._monitor.close(linger=0)
