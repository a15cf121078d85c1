"""`RolloutActor`: one process of rollout work. It owns a `RolloutWorker`, the sockets to the
learner (PUSH unrolls, SUB + snapshot request for weights) and a sampler client for draws.

The same class runs as a Ray actor (cluster and local modes; the learner wraps it with
`ray.remote(max_concurrency=2)` so `stop()` can arrive while `run()` loops) and as a plain
object driven step by step in serial mode (`run_once`).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import threading
import time

import numpy as np
import zmq

from actors.config import ActorConfig
from actors.draws import DrawCache
from actors.rollout import RolloutWorker, configure_torch
from actors.seq_ledger import SeqLedger
from actors.weights_client import WeightsClient
from common import sockets, wire
from common.curve_keys import RunKeys
from common.policy import PolicyConfig
from common.tasks.base import TaskConfig
from common.tasks.registry import task_space
from sampler.client import SamplerClient

log = logging.getLogger(__name__)

FINAL_HEARTBEAT_S = 10.0
"""How long a stopped actor keeps trying to queue its final heartbeat (the learner drains meanwhile)."""


class RolloutActor:
    def __init__(
        self,
        actor_id: int,
        task: TaskConfig,
        policy_cfg: PolicyConfig,
        cfg: ActorConfig,
        endpoints: dict[str, str],
        seed: int = 0,
        sampler_name: str = "",
        keys: RunKeys | None = None,
    ):
        """`sampler_name`: the Ray name of the sampler's actor, if it runs as one; its endpoint is
        looked up through it again on every reconnect, so a restarted sampler on a new port is
        found. A name, not the actor handle: a handle among the constructor arguments of an actor
        Ray may restart makes Ray log an error line on every run (ray-project/ray#53727).
        `keys`: this actor's share of the run's CURVE keys (`RunKeys.for_actor`); every socket of
        this actor authenticates with them."""
        configure_torch(cfg.torch_threads)
        self.actor_id, self.cfg = actor_id, cfg
        self._endpoints = dict(endpoints)
        self._stop = threading.Event()
        self._stall_until = 0.0
        self.sampler = None
        fetch = None
        if endpoints.get("sampler"):
            lookup = _endpoint_lookup(sampler_name) if sampler_name else endpoints["sampler"]
            self.sampler = SamplerClient(lookup, timeout_s=cfg.sampler_timeout_s, retries=cfg.sampler_retries, keys=keys)
            fetch = self._fetch_draws
        self.draws = DrawCache(fetch, task_space(task), cfg.draw_batch, seed=seed + 1)
        self.worker = RolloutWorker(actor_id, task, policy_cfg, cfg, self.draws, seed=seed)
        self.ledger = SeqLedger(cfg.seq_ledger_dir, actor_id)
        self.worker.seq = self.ledger.next_seq()
        self.weights = WeightsClient(actor_id, self.endpoints, cfg.weights_timeout_s, keys=keys)
        self.push = sockets.connect_unroll_push(endpoints["unrolls"], keys)
        self.send_stalls = 0
        """Sends that timed out on a full queue and were retried (the unroll was kept)."""
        self.last_send = time.monotonic()
        self._finished = False

    def endpoints(self) -> dict[str, str]:
        return self._endpoints

    def _fetch_draws(self, n: int) -> tuple[np.ndarray, list[str], list[float]]:
        reply = self.sampler.draw(n)
        return reply.params, list(reply.clip_ids), list(reply.start_s)

    def _send(self, msg) -> bool:
        """Send, retrying while the learner applies backpressure; once stopping, one more try
        (of up to the socket's send timeout) so an unroll collected as the stop came is not
        dropped here. False: not sent (the final heartbeat tells the learner it is lost)."""
        frames = wire.encode(msg)
        if isinstance(msg, wire.UnrollMsg):
            self.ledger.record(msg.seq)
        while True:
            try:
                self.push.send_multipart(frames, copy=False)
                self.last_send = time.monotonic()
                return True
            except zmq.Again:
                self.send_stalls += 1
            if self._stop.is_set():
                return False

    def finish(self) -> bool:
        """Tell the learner this actor stopped: a final heartbeat with the last sequence number
        it used, so the learner counts as lost any unroll up to it that never arrived. Does not
        block; True once sent (then again a no-op)."""
        if self._finished:
            return True
        msg = wire.HeartbeatMsg(actor_id=self.actor_id, seq=self.worker.seq - 1, env_steps=self.worker.env_steps,
                                final=True)
        try:
            self.push.send_multipart(wire.encode(msg), zmq.NOBLOCK, copy=False)
        except zmq.Again:
            return False
        self._finished = True
        return True

    def run_once(self, weights_timeout_ms: int = 0) -> bool:
        """Take new weights if any, then collect and send one unroll. False while no weights yet."""
        new = self.weights.poll(weights_timeout_ms)
        if new is not None:
            try:
                self.worker.set_weights(new)
            except ValueError as exc:  # weights for another network: refuse, keep the old ones
                self.weights.rejected += 1
                log.error("actor %d: refused weights version %d: %s", self.actor_id, new.policy_version, exc)
        if self.worker.policy_version < 0:
            if time.monotonic() - self.last_send > self.cfg.heartbeat_s:
                self._send(wire.HeartbeatMsg(actor_id=self.actor_id, seq=self.worker.seq - 1, env_steps=self.worker.env_steps))
            return False
        msg = self.worker.collect()
        msg = dataclasses.replace(msg, sampler_outages=self.draws.outages)
        self._send(msg)
        return True

    def run(self, max_seconds: float | None = None) -> dict:
        """Loop until `stop()` (or `max_seconds`); returns this actor's counters."""
        deadline = None if max_seconds is None else time.monotonic() + max_seconds
        while not self._stop.is_set() and (deadline is None or time.monotonic() < deadline):
            if time.monotonic() < self._stall_until:  # an injected hang: send nothing at all
                time.sleep(0.05)
                continue
            self.run_once(weights_timeout_ms=0 if self.worker.policy_version >= 0 else 200)
        if self._stop.is_set():  # told to stop (not a time limit): say so while the learner drains
            deadline = time.monotonic() + FINAL_HEARTBEAT_S
            while not self.finish() and time.monotonic() < deadline:
                time.sleep(0.01)
        return self.stats()

    def stop(self) -> None:
        self._stop.set()

    def stall(self, seconds: float) -> None:
        """Fault injection: hang for `seconds` (no unrolls, no heartbeats), then resume."""
        self._stall_until = time.monotonic() + seconds

    def stats(self) -> dict:
        return {
            "actor_id": self.actor_id,
            "env_steps": self.worker.env_steps,
            "unrolls_sent": self.worker.seq,
            "policy_version": self.worker.policy_version,
            "send_stalls": self.send_stalls,
            "sampler_outages": self.draws.outages,
            "pid": os.getpid(),
            "node_id": _node_id(),
        }

    def close(self) -> None:
        self.ledger.close()
        self.push.close(linger=0)
        self.weights.close()
        if self.sampler is not None:
            self.sampler.close()


def _endpoint_lookup(name: str):
    """An endpoint callable that asks the sampler's Ray actor, found by its name, where it listens now."""

    def lookup() -> str:
        import ray  # lazy: heavy (ray), only when the sampler runs as a Ray actor

        return ray.get(ray.get_actor(name).endpoint.remote(), timeout=10)

    return lookup


def _node_id() -> str:
    try:
        import ray  # lazy: heavy (ray), only inside a Ray worker; serial mode reports 'local'

        if ray.is_initialized():
            return ray.get_runtime_context().get_node_id()
    except Exception:  # noqa: BLE001 - best effort, for reports only
        pass
    return "local"
