"""`SamplerService`: the `ShapeSampler` behind a ZeroMQ ROUTER (DESIGN.md "Data flows").

Requests and their replies (messages of `common.wire`):
    DrawRequestMsg   -> DrawReplyMsg     n draws from the buffer (+ clip ids)
    ValueReportMsg   -> OkMsg            (params, V) pairs for the next Vm fit
    TickMsg          -> StatsReplyMsg    fit Vm, maybe refill; stats after the tick
    StatsRequestMsg  -> StatsReplyMsg
    StateRequestMsg  -> StateMsg         the whole state, for the learner's checkpoint
    StateMsg         -> OkMsg            restore that state
    anything else    -> ErrorMsg         counted per kind in `requests/rejected/<kind>`; serving goes on

The socket is used by one thread only (the one running `serve`), so the sampler needs no lock.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Sequence

import numpy as np
import zmq

from common import sockets, wire
from common.params import ParamSpace
from common.rpc import RouterServer
from sampler.config import SamplerConfig
from sampler.shape_sampler import ShapeSampler

log = logging.getLogger(__name__)


class SamplerFault(ValueError):
    """An unexpected exception inside the sampler while answering: replied as an error, logged
    with its traceback, and counted under `internal` instead of stopping the service."""

    kind = "internal"


def bind_address(config: SamplerConfig) -> str:
    """`tcp://host` (a free port) or `tcp://host:port` from the config."""
    return f"tcp://{config.host}" if config.port == 0 else f"tcp://{config.host}:{config.port}"


def _bind(address: str, timeout_s: float = 5.0) -> tuple[zmq.Socket, str]:
    """Bind, retrying while the port is still held by a just-closed socket (a restart in place).

    NOTE: libzmq closes sockets asynchronously in its I/O thread, so re-binding the port of a
    service stopped a moment ago can fail with EADDRINUSE for a few milliseconds."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return sockets.bind_router(address)
        except zmq.ZMQError as exc:
            if exc.errno != zmq.EADDRINUSE or time.monotonic() > deadline:
                raise RuntimeError(f"sampler cannot bind {address}: {exc}; choose another port or host") from exc
            time.sleep(0.05)


class SamplerService:
    """Owns a bound ROUTER and a `ShapeSampler`; `serve` answers until its stop event is set."""

    def __init__(self, config: SamplerConfig, space: ParamSpace,
                 clips: Sequence[tuple[str, str]] | None = None, address: str | None = None):
        """`address` overrides the config's host/port (e.g. `tcp://127.0.0.1:5555` to restart
        a service where its clients already look)."""
        self.config = config
        self.sampler = ShapeSampler(config, space, clips)
        sock, self.endpoint = _bind(address or bind_address(config))
        self.server = RouterServer(sock, self._handle, "sampler")
        if self.sampler.balancer is not None:
            log.info("sampler: motion balancer over %d clips:\n%s", len(self.sampler.balancer.clip_ids),
                     self.sampler.balancer.table())
        log.info("sampler: serving %s on %s", list(space.names), self.endpoint)

    def _handle(self, msg: Any) -> Any:
        try:
            return self._dispatch(msg)
        except (wire.WireError, ValueError):
            raise
        except Exception as exc:  # a sampler bug must not take the service down with it
            log.exception("sampler: internal error on %s", type(msg).KIND)
            raise SamplerFault(f"internal error on {type(msg).KIND}: {type(exc).__name__}: {exc}") from exc

    def _dispatch(self, msg: Any) -> Any:
        s = self.sampler
        if isinstance(msg, wire.DrawRequestMsg):
            params, clips = s.draw(msg.n)
            return wire.DrawReplyMsg(params=params.astype(np.float32), clip_ids=clips,
                                     buffer_generation=s.generation)
        if isinstance(msg, wire.ValueReportMsg):
            m = s.report(msg.params, msg.values)
            return wire.OkMsg(info=f"stored {m} pairs")
        if isinstance(msg, wire.TickMsg):
            if not isinstance(msg.iteration, int) or isinstance(msg.iteration, bool) or msg.iteration < 0:
                raise ValueError(f"tick iteration = {msg.iteration!r}; allowed: an integer >= 0")
            s.tick(msg.iteration)
            return wire.StatsReplyMsg(stats=self.stats())
        if isinstance(msg, wire.StatsRequestMsg):
            return wire.StatsReplyMsg(stats=self.stats())
        if isinstance(msg, wire.StateRequestMsg):
            state = s.state_dict()
            return wire.StateMsg(meta=state["meta"], arrays=state["arrays"])
        if isinstance(msg, wire.StateMsg):
            try:
                s.load_state_dict({"meta": msg.meta, "arrays": msg.arrays})
            except (KeyError, TypeError) as exc:
                raise ValueError(f"sampler state lacks or mistypes {exc}; send what StateRequestMsg returned") from None
            return wire.OkMsg(info=f"restored generation {s.generation}")
        raise wire.WireError(f"the sampler does not answer {type(msg).KIND!r} messages", "unknown_kind")

    def stats(self) -> dict[str, float]:
        """`ShapeSampler.stats()` plus `requests/served`, `requests/rejected` (all kinds) and
        `requests/rejected/<kind>` (malformed, version, unknown_kind, nonfinite, invalid, ...)."""
        out = self.sampler.stats()
        out["requests/served"] = float(self.server.served)
        out["requests/rejected"] = float(sum(self.server.rejected.values()))
        for kind, count in sorted(self.server.rejected.items()):
            out[f"requests/rejected/{kind}"] = float(count)
        return out

    def serve_pending(self, timeout_ms: int = 0) -> int:
        """Answer what arrives within `timeout_ms`; returns how many requests were handled."""
        return self.server.serve_pending(timeout_ms)

    def serve(self, stop_event: threading.Event, poll_ms: int = 50) -> None:
        """Answer requests until `stop_event` is set (checked every `poll_ms`), then close."""
        try:
            while not stop_event.is_set():
                self.server.serve_pending(poll_ms)
        finally:
            self.close()

    def close(self) -> None:
        if not self.server.sock.closed:
            self.server.sock.close(linger=0)
