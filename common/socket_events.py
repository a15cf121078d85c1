"""Counts what happens to the connections of one bound socket, from its monitor events: peers
the CURVE handshake refused, and connections that ended.

libzmq drops a connection whose peer sends a message over the socket's MAXMSGSIZE; the message
and the drop leave no other trace (no error, no event of their own: only DISCONNECTED, the same
as a peer that closed). Counting every ended connection makes such a drop visible: on the
learner's unroll socket an actor disconnects only when it stops or restarts, so disconnects
beyond those are messages libzmq refused. A socket has one monitor, so the handshake refusals
(`curve_keys.REFUSAL_EVENTS`) are counted here too when the socket is a CURVE server.
"""

from __future__ import annotations

import zmq
from zmq.utils.monitor import recv_monitor_message

from common.curve_keys import REFUSAL_EVENTS

MAX_EVENTS_PER_POLL = 10_000
"""Events read by one `poll`: a storm of connections cannot hold the caller (the rest wait)."""


class ConnectionEvents:
    """Monitor of one socket; `poll(counters)` adds `disconnects` and, with `with_refusals`,
    `rejected/auth_*` (as `curve_keys.RefusalCounter` names them) to a Counter."""

    def __init__(self, sock: zmq.Socket, with_refusals: bool):
        self.names = {zmq.EVENT_DISCONNECTED: "disconnects"}
        if with_refusals:
            self.names.update({event: f"rejected/{kind}" for event, kind in REFUSAL_EVENTS.items()})
        events = 0
        for event in self.names:
            events |= event
        self._sock = sock
        self._monitor = sock.get_monitor_socket(events)

    def poll(self, counters) -> int:
        """Add the events seen since the last call to `counters`; returns how many. Never blocks."""
        n = 0
        for _ in range(MAX_EVENTS_PER_POLL):
            try:
                event = recv_monitor_message(self._monitor, flags=zmq.NOBLOCK)
            except zmq.ZMQError:  # zmq.Again (nothing more) or a closed monitor
                return n
            name = self.names.get(event["event"])
            if name:
                counters[name] += 1
                n += 1
        return n

    def close(self) -> None:
        """Stop monitoring, then close the monitor's end. NOTE: before the socket closes: a
        socket closed with its monitor still on left later sockets of the process deaf (in a
        test making many transports, every PULL after the 25th received nothing)."""
        if not self._sock.closed:
            self._sock.disable_monitor()
        self._monitor.close(linger=0)
