"""`SamplerClient`: typed calls to the sampler service over `common.rpc.RpcClient` (Lazy Pirate).

Every call retries with a fresh socket after `timeout_s` and raises `ServiceUnavailable` after
`retries` tries; actors then keep their last draws and count an outage (`UnrollMsg.sampler_outages`).
An `ErrorMsg` reply (bad input) raises `common.wire.WireError` carrying the service's reason.
"""

from __future__ import annotations

import secrets
import dataclasses
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from common import wire
from common.curve_keys import ACTOR, RunKeys
from common.rpc import RpcClient, ServiceUnavailable

__all__ = ["Draws", "SamplerClient", "ServiceUnavailable"]


@dataclass(frozen=True)
class Draws:
    params: np.ndarray
    """`[n, n_params]` float32 task/shape parameters in the space's order."""
    clip_ids: list[str]
    """n clip ids, or empty when the sampler has no clips."""
    buffer_generation: int
    """MCMC refills so far when these were drawn."""
    start_s: list[float] = dataclasses.field(default_factory=list)
    """n start times (s) in those clips, or empty: time bins off, the environment draws one."""


class SamplerClient:
    """One client per thread (ZeroMQ sockets are not thread-safe)."""

    def __init__(self, endpoint: str | Callable[[], str], timeout_s: float = 2.0, retries: int = 3,
                 client_id: int = 0, keys: RunKeys | None = None, role: str = ACTOR):
        """`endpoint` may be a callable returning the current endpoint (looked up again on
        every reconnect, e.g. from a restarted Ray actor). `keys`, `role`: the run's CURVE keys
        and this client's role (only the learner may report values, tick, or get and set state)."""
        self.rpc = RpcClient(endpoint, timeout_s=timeout_s, retries=retries, keys=keys, role=role)
        self.client_id = client_id
        self._nonce = secrets.token_hex(8)
        self._reports = 0

    def draw(self, n: int) -> Draws:
        reply = self.rpc.call(wire.DrawRequestMsg(n=int(n), client_id=self.client_id), wire.DrawReplyMsg)
        return Draws(params=np.array(reply.params), clip_ids=list(reply.clip_ids),
                     buffer_generation=int(reply.buffer_generation), start_s=list(reply.start_s))

    def new_report_id(self) -> str:
        """An id unique to one report (this client's random nonce and a counter)."""
        self._reports += 1
        return f"{self._nonce}-{self._reports}"

    def report(self, params: np.ndarray, values: np.ndarray,
               clips: tuple[Sequence[str], Sequence[int], Sequence[int]] = ((), (), ()),
               failures: tuple[Sequence[str], Sequence[float]] = ((), ()), report_id: str | None = None,
               pair_clips: Sequence[str] = ()) -> str:
        """Send (s_b `[m, d]`, V(s) `[m]`) pairs for the marginal value fit, `clips`: the
        training segments per clip since the last report, (ids, segments, tracked), for adaptive
        clip sampling, and `failures`: (clip ids, clip times in s) of the failed segments, for
        the time bins (at most `wire.MAX_FAILURE_TIMES`), and `pair_clips`: the clip of each
        pair's episode (only to a sampler with `shape_by_class`). Returns the service's note (pairs
        stored; failure times refused and why).

        Idempotent: the report carries an id unique to this call (this client's random nonce
        and a counter), and every retry of the call resends it, so the service stores the pairs
        once even when a reply was lost and the request sent again. A caller that keeps an
        undelivered report to send later passes the `report_id` it first used (`new_report_id`)."""
        msg = wire.ValueReportMsg(params=np.asarray(params, dtype=np.float32),
                                  values=np.asarray(values, dtype=np.float32).reshape(-1),
                                  report_id=report_id or self.new_report_id(),
                                  clip_ids=[str(c) for c in clips[0]], clip_segments=[int(n) for n in clips[1]],
                                  clip_tracked=[int(t) for t in clips[2]],
                                  fail_clip_ids=[str(c) for c in failures[0]], fail_times_s=[float(t) for t in failures[1]],
                                  pair_clip_ids=[str(c) for c in pair_clips])
        return self.rpc.call(msg, wire.OkMsg).info

    def tick(self, iteration: int) -> dict[str, float]:
        """Policy iteration `iteration` is done; returns the stats after the tick (a refill
        every `p_mcmc` iterations can make this take tens of milliseconds)."""
        return dict(self.rpc.call(wire.TickMsg(iteration=int(iteration)), wire.StatsReplyMsg).stats)

    def stats(self) -> dict[str, float]:
        return dict(self.rpc.call(wire.StatsRequestMsg(), wire.StatsReplyMsg).stats)

    def get_state(self) -> dict[str, Any]:
        """`{"meta": ..., "arrays": {name: np.ndarray}}` (arrays copied: writable, not views of frames)."""
        reply = self.rpc.call(wire.StateRequestMsg(), wire.StateMsg)
        return {"meta": reply.meta, "arrays": {k: np.array(v) for k, v in reply.arrays.items()}}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state returned by `get_state` (or `ShapeSampler.state_dict`)."""
        arrays = {k: np.ascontiguousarray(np.asarray(v)) for k, v in state["arrays"].items()}
        self.rpc.call(wire.StateMsg(meta=state["meta"], arrays=arrays), wire.OkMsg)

    def close(self) -> None:
        self.rpc.close()
