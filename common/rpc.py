"""Request/reply over DEALER -> ROUTER with the ZeroMQ guide's Lazy Pirate client.

The client sends a request, polls for the reply with a timeout, and on timeout closes its
socket, looks the endpoint up again (the service may have moved or restarted) and retries.
The server decodes each request with the wire codec; a malformed one gets an `ErrorMsg`
reply and is counted per kind, and the server keeps serving. No peer can block it: every reply
is sent without waiting (a peer whose pipe is full, because it does not read its replies, loses
that reply, counted under `dropped/full_pipe`; one that has gone, under `dropped/departed`), and
a peer with `MAX_BACKLOG` unread replies in a row has its further requests dropped unanswered
(`dropped/over_backlog`), all but every `MAX_BACKLOG`-th, whose reply going through shows that
the peer reads again and lifts the bound.
"""

from __future__ import annotations

import collections
import logging
from typing import Any, Callable

import zmq

from common import curve_keys, sockets, wire
from common.curve_keys import ACTOR, RefusalCounter, RunKeys

log = logging.getLogger(__name__)


class ServiceUnavailable(RuntimeError):
    """No reply after every retry; the caller decides how to degrade."""


class RpcClient:
    """Lazy Pirate client. `endpoint` is a string or a callable returning the current one."""

    def __init__(self, endpoint: str | Callable[[], str], timeout_s: float = 2.0, retries: int = 3,
                 keys: RunKeys | None = None, role: str = ACTOR):
        """`keys`, `role`: this run's CURVE keys and the role this client speaks in."""
        self._lookup = endpoint if callable(endpoint) else (lambda: endpoint)
        self.keys, self.role = keys, role
        self.timeout_ms = int(timeout_s * 1000)
        self.retries = retries
        self.reconnects = 0
        self._sock: zmq.Socket | None = None

    def _socket(self) -> zmq.Socket:
        if self._sock is None:
            try:
                endpoint = self._lookup()
            except Exception as exc:  # noqa: BLE001 - a lookup that fails means "not there now"
                raise ServiceUnavailable(f"could not look up the service endpoint: {exc}") from None
            self._sock = sockets.connect_dealer(endpoint, self.keys, self.role)
        return self._sock

    def _reset(self) -> None:
        if self._sock is not None:
            self._sock.close(linger=0)
            self._sock = None
        self.reconnects += 1

    def call(self, request: Any, expect: type | tuple[type, ...]) -> Any:
        """Send `request`, return the decoded reply of type `expect`.

        Raises `ServiceUnavailable` after `retries` timeouts, `wire.WireError` if the service
        answered with an `ErrorMsg` (its reason is the message) or with garbage.
        """
        frames = wire.encode(request)
        for _ in range(self.retries):
            sock = self._socket()
            sock.send_multipart([b"", *frames], copy=False)
            if sock.poll(self.timeout_ms, zmq.POLLIN):
                reply_frames = sock.recv_multipart(copy=False)
                reply = wire.decode(reply_frames[1:])
                if isinstance(reply, wire.ErrorMsg):
                    raise wire.WireError(f"service refused {type(request).KIND}: {reply.reason}", reply.error_kind)
                if not isinstance(reply, expect):
                    raise wire.WireError(f"expected {expect} in reply to {type(request).KIND}, got {type(reply).KIND}")
                return reply
            # NOTE: a DEALER that timed out may still receive the late reply later; a fresh socket
            # guarantees the next reply we read answers the next request (Lazy Pirate).
            self._reset()
        raise ServiceUnavailable(f"no reply to {type(request).KIND} after {self.retries} tries of {self.timeout_ms} ms")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close(linger=0)
            self._sock = None


MAX_BACKLOG = 64
"""Replies a peer may leave unread in a row (each dropped on its full pipe) before the server
stops answering it: a peer that never reads costs the server no more than this."""
MAX_PEERS_TRACKED = 4096
"""Peers whose backlog is remembered; the oldest is forgotten beyond this (identities are per connection)."""


class RouterServer:
    """Decode-dispatch-reply on a bound ROUTER socket; never raises on a peer's bad input and
    never blocks on a peer that does not read (see the module docstring)."""

    def __init__(self, sock: zmq.Socket, handler: Callable[[Any], Any], name: str,
                 dims: dict[str, int] | None = None, roles: dict[type, frozenset[str]] | None = None):
        """`dims` pins shape names of the requests (`wire.decode`), e.g. {"n_params": 3}.
        `roles`: on a CURVE socket, the client roles allowed to send each message type (a type
        not listed: any client of the run); a request from another role is refused as
        `forbidden`. Peers the CURVE handshake refused are counted as `auth_*`."""
        self.sock = sock
        self.handler = handler
        self.name = name
        self.dims = dims
        self.roles = roles or {}
        self.secured = bool(sock.get(zmq.CURVE_SERVER))
        self.refusals = RefusalCounter(sock) if self.secured else None
        self.rejected: collections.Counter[str] = collections.Counter()
        self.served = 0
        self.dropped: collections.Counter[str] = collections.Counter()
        """Replies not delivered, by reason: `full_pipe` (the peer does not read), `departed` (it
        had gone: a client that timed out and reconnected), `over_backlog` (requests of a peer past
        `MAX_BACKLOG` unread replies, dropped unanswered)."""
        self._backlog: collections.OrderedDict[bytes, int] = collections.OrderedDict()

    def serve_pending(self, timeout_ms: int = 0, max_requests: int = 1000) -> int:
        """Answer requests that arrive within `timeout_ms`; returns how many were handled."""
        handled = 0
        if self.refusals is not None:
            self.refusals.poll(self.rejected)
        while handled < max_requests and self.sock.poll(timeout_ms if handled == 0 else 0, zmq.POLLIN):
            frames = self.sock.recv_multipart(copy=False)
            handled += 1
            identity = frames[0].bytes
            backlog = self._backlog.get(identity, 0)
            if backlog >= MAX_BACKLOG:
                self._backlog[identity] = backlog + 1
                if (backlog - MAX_BACKLOG) % MAX_BACKLOG != MAX_BACKLOG - 1:
                    self.dropped["over_backlog"] += 1
                    continue
                # every MAX_BACKLOG-th request of such a peer is answered: a reply that goes through shows it reads again
            # DEALER clients put an empty delimiter frame first; tolerate REQ-style and bare ones.
            body = frames[2:] if len(frames) > 1 and len(frames[1].bytes) == 0 else frames[1:]
            try:
                request = wire.decode(body, dims=self.dims)
                self._check_role(request, curve_keys.role_of(frames[0]))
                wire.check_finite(request)
                reply = wire.encode(self.handler(request))
            except Exception as exc:  # noqa: BLE001 - nothing a peer sends may stop the service
                reply = wire.encode(self._refuse(exc))
            self.served += 1
            self._reply(identity, reply)
        return handled

    def _reply(self, identity: bytes, reply: list) -> None:
        """Send without waiting; a reply that cannot go now is dropped and counted (see the module docstring)."""
        try:
            self.sock.send_multipart([identity, b"", *reply], flags=zmq.NOBLOCK, copy=False)
        except zmq.Again:  # the peer's pipe is full: it does not read its replies
            self.dropped["full_pipe"] += 1
            self._backlog[identity] = max(self._backlog.pop(identity, 0), 0) + 1
            while len(self._backlog) > MAX_PEERS_TRACKED:
                self._backlog.popitem(last=False)
            return
        except zmq.ZMQError as exc:  # EHOSTUNREACH with ROUTER_MANDATORY: the peer left
            self.dropped["departed"] += 1
            self._backlog.pop(identity, None)
            log.debug("%s: could not reply to a departed peer: %s", self.name, exc)
            return
        self._backlog.pop(identity, None)

    @property
    def undeliverable(self) -> int:
        """Replies not delivered, every reason."""
        return sum(self.dropped.values())

    def _check_role(self, request: Any, role: str) -> None:
        allowed = self.roles.get(type(request))
        if self.secured and allowed is not None and role not in allowed:
            raise wire.WireError(f"{type(request).KIND} is taken only from {' or '.join(sorted(allowed))}, "
                                 f"not from {role or 'an unknown peer'}", "forbidden")

    def close(self) -> None:
        if self.refusals is not None:
            self.refusals.close()
        if not self.sock.closed:
            self.sock.close(linger=0)

    def _refuse(self, exc: Exception) -> wire.ErrorMsg:
        """Count a refused request under its kind; the ErrorMsg that answers it."""
        kind = getattr(exc, "kind", None)
        if not isinstance(kind, str):
            kind = "invalid" if isinstance(exc, ValueError) else "internal"
        if self.rejected[kind] == 0:
            log.warning("%s: rejected a request (%s): %s", self.name, kind, exc)
        self.rejected[kind] += 1
        return wire.ErrorMsg(reason=str(exc)[:4096], error_kind=kind[:64])
