"""Receives policy weights: PUB/SUB for every new version, plus a snapshot request to the
learner's ROUTER on (re)connect, because PUB drops messages for slow joiners.

Non-blocking by design (`poll` with a timeout) so the same code runs in a Ray actor's loop and
in serial mode, where the learner answers the request on the same thread between polls.
"""

from __future__ import annotations

import logging
import time
from typing import Callable

import zmq

from common import sockets, wire
from common.curve_keys import RunKeys

log = logging.getLogger(__name__)


class WeightsClient:
    def __init__(self, actor_id: int, endpoints: Callable[[], dict[str, str]], timeout_s: float = 2.0,
                 keys: RunKeys | None = None):
        self.actor_id = actor_id
        self.keys = keys
        self.endpoints = endpoints
        """Looked up again on every (re)connect: the learner may have moved or restarted."""
        self.timeout_s = timeout_s
        self.sub: zmq.Socket | None = None
        self.dealer: zmq.Socket | None = None
        self.requested_at: float | None = None
        self.version = -1
        self.rejected = 0
        self.connect()

    def connect(self) -> None:
        self.close()
        ep = self.endpoints()
        self.sub = sockets.connect_weights_sub(ep["weights_pub"], self.keys)
        self.dealer = sockets.connect_dealer(ep["weights_router"], self.keys)
        self.requested_at = None

    def request_snapshot(self) -> None:
        assert self.dealer is not None
        frames = wire.encode(wire.WeightsRequestMsg(actor_id=self.actor_id, have_version=self.version))
        self.dealer.send_multipart([b"", *frames], copy=False)
        self.requested_at = time.monotonic()

    def poll(self, timeout_ms: int = 0) -> wire.WeightsMsg | None:
        """Return the newest weights newer than what we have, or None.

        Retries the snapshot request (on a fresh socket) if its reply is overdue.
        """
        assert self.sub is not None and self.dealer is not None
        if self.version < 0 and (self.requested_at is None or time.monotonic() - self.requested_at > self.timeout_s):
            if self.requested_at is not None:  # Lazy Pirate: the reply is overdue, start afresh
                self.connect()
            self.request_snapshot()
        newest: wire.WeightsMsg | None = None
        poller = zmq.Poller()
        poller.register(self.sub, zmq.POLLIN)
        poller.register(self.dealer, zmq.POLLIN)
        events = dict(poller.poll(timeout_ms))
        while events:
            for sock in events:
                frames = sock.recv_multipart(copy=False)
                body = frames[1:] if sock is self.dealer else frames
                try:
                    msg = wire.decode(body, expect=wire.WeightsMsg)  # tensors finite by their wire rule
                except wire.WireError as exc:
                    self.rejected += 1
                    log.warning("actor %d: rejected weights message: %s", self.actor_id, exc)
                    continue
                if sock is self.dealer:
                    self.requested_at = None
                if msg.policy_version > max(self.version, newest.policy_version if newest else -1):
                    newest = msg
            events = dict(poller.poll(0))
        if newest is not None:
            self.version = newest.policy_version
        return newest

    def close(self) -> None:
        for sock in (self.sub, self.dealer):
            if sock is not None:
                sock.close(linger=0)
        self.sub = self.dealer = None
