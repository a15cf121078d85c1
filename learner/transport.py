"""The learner's sockets: PULL for unrolls, PUB for weights, ROUTER for weight snapshots.

Every received message is decoded and validated here; what fails is counted per kind and
logged once per kind, so nothing malformed reaches the optimizer and no loss goes uncounted.
"""

from __future__ import annotations

import collections
import logging
import time

import numpy as np
import zmq

from common import sockets, wire
from common.rpc import RouterServer

log = logging.getLogger(__name__)


class LearnerTransport:
    def __init__(self, host: str, obs_dim: int, act_dim: int, n_params: int, port_base: int = 0):
        """`port_base` 0 binds free ports; else unrolls on port_base, weights PUB on +1, snapshots on +2."""
        addr = lambda i: f"tcp://{host}:{port_base + i}" if port_base else f"tcp://{host}"  # noqa: E731
        self.pull, unrolls = sockets.bind_unroll_pull(addr(0))
        self.pub, weights_pub = sockets.bind_weights_pub(addr(1))
        router, weights_router = sockets.bind_router(addr(2))
        self.endpoints = {"unrolls": unrolls, "weights_pub": weights_pub, "weights_router": weights_router}
        self.snapshots = RouterServer(router, self._on_request, name="weights")
        self.dims = (obs_dim, act_dim, n_params)
        self.current: wire.WeightsMsg | None = None
        self.counters: collections.Counter[str] = collections.Counter()
        self.last_seq: dict[int, int] = {}
        self.resumed = False
        """Set by `load_state_dict`: each actor's first unroll sets its baseline, not seq 0."""
        """Highest unroll sequence number received per actor (kept across learner restarts)."""
        self.received: collections.Counter[int] = collections.Counter()
        """Valid unrolls received per actor."""
        self.sampler_outages: dict[int, int] = {}
        """Latest cumulative sampler-outage count each actor reported."""
        self.last_seen: dict[int, float] = {}
        self.bytes_received = 0
        self.poller = zmq.Poller()
        self.poller.register(self.pull, zmq.POLLIN)
        self.poller.register(router, zmq.POLLIN)

    def _on_request(self, msg) -> wire.WeightsMsg | wire.ErrorMsg:
        if not isinstance(msg, wire.WeightsRequestMsg):
            raise wire.WireError(f"the weights service answers weights_request only, not {type(msg).KIND}", "unknown_kind")
        if self.current is None:
            return wire.ErrorMsg(reason="no weights published yet; ask again", error_kind="not_ready")
        self.counters["snapshots_served"] += 1
        return self.current

    def publish(self, msg: wire.WeightsMsg) -> None:
        self.current = msg
        self.pub.send_multipart(wire.encode(msg), copy=False)

    def _reject(self, kind: str, reason: str) -> None:
        if self.counters[f"rejected/{kind}"] == 0:
            log.warning("rejected an unroll-channel message (%s): %s", kind, reason)
        self.counters[f"rejected/{kind}"] += 1

    def _validate_shapes(self, m: wire.UnrollMsg) -> None:
        obs_dim, act_dim, n_params = self.dims
        if m.obs.ndim != 3 or m.obs.shape[2] != obs_dim:
            raise wire.WireError(f"unroll obs shape {m.obs.shape}, expected [T, N, {obs_dim}]", "bad_shape")
        T, N = m.obs.shape[:2]
        expected = {
            "next_obs": (T, N, obs_dim), "actions": (T, N, act_dim), "logp": (T, N), "rewards": (T, N),
            "terminated": (T, N), "truncated": (T, N), "params": (T, N, n_params),
        }
        for name, shape in expected.items():
            if getattr(m, name).shape != shape:
                raise wire.WireError(f"unroll {name} shape {getattr(m, name).shape}, expected {shape}", "bad_shape")
        if m.terminated.dtype != np.bool_ or m.truncated.dtype != np.bool_:
            raise wire.WireError("unroll terminated/truncated must be bool arrays", "bad_shape")

    def receive(self, timeout_ms: int, policy_version: int, max_policy_lag: int) -> list[wire.UnrollMsg]:
        """Serve snapshot requests and return the valid, fresh unrolls that arrive within
        `timeout_ms` (returns as soon as something arrived)."""
        out: list[wire.UnrollMsg] = []
        events = dict(self.poller.poll(timeout_ms))
        while events:
            if self.snapshots.sock in events:
                self.snapshots.serve_pending(0)
            if self.pull in events:
                for _ in range(256):
                    try:
                        frames = self.pull.recv_multipart(zmq.NOBLOCK, copy=False)
                    except zmq.Again:
                        break
                    msg = self._accept(frames, policy_version, max_policy_lag)
                    if msg is not None:
                        out.append(msg)
            events = dict(self.poller.poll(0))
            if out:
                break
        return out

    def _accept(self, frames, policy_version: int, max_policy_lag: int) -> wire.UnrollMsg | None:
        self.bytes_received += sum(len(f.buffer) for f in frames)
        try:
            msg = wire.decode(frames, expect=(wire.UnrollMsg, wire.HeartbeatMsg))
            wire.check_finite(msg)
            if isinstance(msg, wire.UnrollMsg):
                self._validate_shapes(msg)
        except wire.WireError as exc:
            self._reject(exc.kind, str(exc))
            return None
        self.last_seen[msg.actor_id] = time.monotonic()
        if isinstance(msg, wire.HeartbeatMsg):
            self.counters["heartbeats"] += 1
            return None
        # Numbering starts at 0 and, with a sequence ledger, survives actor restarts: any
        # number skipped is an unroll that was sent (or queued) and never arrived.
        previous = self.last_seq.get(msg.actor_id, msg.seq - 1 if self.resumed else -1)
        if msg.seq > previous + 1:
            gap = msg.seq - previous - 1
            if self.counters["seq_gap_unrolls"] == 0:
                log.warning("actor %d skipped %d unroll(s) (seq %d -> %d)", msg.actor_id, gap, previous, msg.seq)
            self.counters["seq_gap_unrolls"] += gap
        elif msg.seq <= previous:
            self.counters["seq_restarts"] += 1  # an actor without a ledger restarted from 0
        self.last_seq[msg.actor_id] = msg.seq
        self.received[msg.actor_id] += 1
        self.sampler_outages[msg.actor_id] = msg.sampler_outages
        self.counters["unrolls_received"] += 1
        self.counters["steps_received"] += int(msg.rewards.size)
        if msg.policy_version < 0 or policy_version - msg.policy_version > max_policy_lag:
            self.counters["stale_unrolls"] += 1
            return None
        return msg

    def state_dict(self) -> dict:
        """What a resumed learner needs to keep its counters where it left off."""
        return {
            "last_seq": {str(k): int(v) for k, v in self.last_seq.items()},
            "counters": {k: int(v) for k, v in self.counters.items()},
        }

    def load_state_dict(self, state: dict) -> None:
        """Counters only. The checkpoint's `last_seq` is as old as the checkpoint: the unrolls
        received between it and the stop were trained on, not lost, and the actors' ledgers
        number on from them, so each actor's first unroll after a resume is the new baseline
        (otherwise every resume counted them as gaps: "gaps 49" after 9 resumes)."""
        self.last_seq = {}
        self.resumed = True
        self.counters.update(state["counters"])

    def close(self) -> None:
        for sock in (self.pull, self.pub, self.snapshots.sock):
            sock.close(linger=0)
