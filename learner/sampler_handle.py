"""The learner's handle on the sampler service: starts it (a Ray actor in cluster and local
modes, a thread in serial mode), talks to it through the same ZeroMQ client as the actors, and
stops it. A sampler that does not answer costs the learner its metrics for that iteration,
never the run."""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import logging
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from common.curve_keys import LEARNER, RunKeys
from common.params import ParamSpace
from common.rpc import ServiceUnavailable
from common.wire import WireError
from learner import cluster
from sampler.actor import SamplerActor, start_in_thread
from sampler.client import SamplerClient
from sampler.config import SamplerConfig

log = logging.getLogger(__name__)

MAX_UNSENT_PAIRS = 65536
"""Value pairs kept for a sampler that does not answer (16 iterations at the default 4096 per
iteration); the oldest beyond it are dropped and counted."""
QUICK_TIMEOUT_S = 1.0
"""The one try a sampler call gets inside `quick()` (the stop path)."""
RETRY_AFTER_S = 10.0
"""After the sampler failed to answer, the learner leaves it alone this long."""
LEARNER_TIMEOUT_S = 3.0
"""A tick may fit Vm and refill the buffer (tenths of a second; more on a loaded machine)."""


def pairs_taken_of(state: dict[str, Any]) -> int:
    """`ShapeSampler.pairs_taken` of a saved sampler state (older states: fitted + pending)."""
    meta = state["meta"]
    if "pairs_taken" in meta:
        return int(meta["pairs_taken"])
    return int(meta["vm"]["pairs_seen"]) + len(state["arrays"].get("pending_values", ()))


@dataclass(frozen=True)
class Report:
    """One iteration's value report, kept until the sampler takes it (resent with the same id)."""

    report_id: str
    params: np.ndarray
    values: np.ndarray
    clips: tuple
    failures: tuple = ((), ())
    pair_clips: tuple = ()
    """The clip of each pair's episode (a sampler with `shape_by_class`); empty otherwise."""


@dataclass
class SamplerHandle:
    endpoint: str
    client: SamplerClient
    config: SamplerConfig
    space: ParamSpace
    clips: Sequence[tuple[str, str]]
    ray_handle: Any = None
    ray_name: str = ""
    """The sampler actor's Ray name (unique per run): rollout actors look it up by name, never
    holding its handle among their constructor arguments (`actors.actor`)."""
    thread: threading.Thread | None = None
    stop_event: threading.Event | None = None
    failures: int = 0
    saved_state: dict[str, Any] | None = None
    """The sampler state of the newest checkpoint: restored into a restarted sampler."""
    restores: int = 0
    """Restarts after which the sampler had its state back (its own file, or the checkpoint's)."""
    restarts: int = 0
    """Sampler restarts seen (its start time changed between two answers)."""
    started_seen: float = 0.0
    taken_expected: float = 0.0
    """The sampler's `vm/pairs_taken` as the learner expects it: its last answer plus the pairs delivered since."""
    pairs_delivered: int = 0
    pairs_lost: int = 0
    """Value pairs that never reached a fit: dropped from the full queue, refused, held by a
    sampler that restarted before saving them, or still queued at stop."""
    unsent: collections.deque = dataclasses.field(default_factory=collections.deque)
    """Reports the sampler did not take yet, oldest first (at most `MAX_UNSENT_PAIRS` pairs)."""
    down_until: float = 0.0

    @staticmethod
    def start(config: SamplerConfig, space: ParamSpace, clips: Sequence[tuple[str, str]], ctx,
              keys: RunKeys | None = None, durations: Mapping[str, float] | None = None) -> "SamplerHandle":
        """Start the service (with the run's CURVE keys as the sampler holds them, and the clips'
        lengths for start times) and a client that speaks as the learner."""
        service_keys = keys.for_sampler() if keys is not None else None

        def client(endpoint) -> SamplerClient:
            return SamplerClient(endpoint, timeout_s=LEARNER_TIMEOUT_S, retries=2, keys=keys, role=LEARNER)

        if ctx is None:
            service, thread, stop_event = start_in_thread(config, space, clips, keys=service_keys, durations=durations)
            endpoint = service.endpoint
            return SamplerHandle(endpoint, client(endpoint), config, space, clips, thread=thread, stop_event=stop_event)
        import ray  # lazy: heavy (ray), only in the Ray modes

        opts = cluster.actor_options(ctx, cluster.SAMPLER_RESOURCE, 0.01, 0.0)
        opts.pop("scheduling_strategy", None)
        if config.device == "cuda" or (config.device == "auto" and torch.cuda.is_available()):
            opts["num_gpus"] = 0.1  # NOTE: Ray hides the GPUs from an actor that asks for none
        name = f"morphmimic-sampler-{uuid.uuid4().hex[:12]}"
        remote = ray.remote(SamplerActor).options(name=name, max_restarts=-1, **opts)
        handle = remote.remote(config, space, list(clips), service_keys, dict(durations or {}))
        endpoint = ray.get(handle.endpoint.remote(), timeout=120)

        def lookup() -> str:  # a restarted sampler binds a new port: ask it where, every reconnect
            return ray.get(handle.endpoint.remote(), timeout=10)

        return SamplerHandle(endpoint, client(lookup), config, space, clips, ray_handle=handle, ray_name=name)

    def _call(self, what: str, fn, default):
        """Call the sampler; on failure count it and, for an outage, skip further calls for
        `RETRY_AFTER_S` (a circuit breaker: the learner must not spend each iteration in timeouts)."""
        if time.monotonic() < self.down_until:
            return default
        try:
            return fn()
        except (ServiceUnavailable, WireError) as exc:
            self.failures += 1
            if isinstance(exc, ServiceUnavailable):
                self.down_until = time.monotonic() + RETRY_AFTER_S
            log.warning("sampler %s failed (%s); continuing without it", what, exc)
            return default

    def report_and_tick(self, params: np.ndarray, values: np.ndarray, iteration: int,
                        clips: tuple[list[str], list[int], list[int]] = ([], [], []),
                        failures: tuple[list[str], list[float]] = ([], []),
                        pair_clips: Sequence[str] = ()) -> dict[str, float]:
        """Queue the value pairs, `clips` (the training segments per clip since the last call:
        ids, segments, tracked; only clips the sampler draws are sent) and `failures` (clip ids
        and clip times of the failed segments, sent only when the sampler keeps time bins; the
        sampler checks every time against its clip), deliver what is queued, then tick. Pairs
        the sampler cannot take now wait in a bounded queue (`MAX_UNSENT_PAIRS`) and go with the
        next call that reaches it; the oldest are dropped beyond the bound and counted in
        `pairs_lost`, as are pairs a restarted sampler no longer holds.

        `pair_clips`: the clip of each pair's episode, sent only to a sampler with
        `shape_by_class` (which needs one per pair); a pair without a clip it draws cannot be
        fitted there, so it is left out and counted in `pairs_lost`."""
        known = {cid for cid, _ in self.clips}
        if self.config.shape_by_class:
            pair_clips = list(pair_clips) if len(pair_clips) == len(values) else [""] * len(values)
            fit = [i for i, cid in enumerate(pair_clips) if cid in known]
            if len(fit) < len(values):
                self.pairs_lost += len(values) - len(fit)
                log.warning("%d value pairs without a clip the sampler draws: not sent (lost, counted)",
                            len(values) - len(fit))
                params, values = np.asarray(params)[fit], np.asarray(values)[fit]
                pair_clips = [pair_clips[i] for i in fit]
        else:
            pair_clips = []
        keep = [i for i, cid in enumerate(clips[0]) if cid in known]
        clips = tuple([part[i] for i in keep] for part in clips)
        keep = [i for i, cid in enumerate(failures[0]) if cid in known] if self.config.time_bin_s > 0 else []
        failures = tuple([part[i] for i in keep] for part in failures)
        if len(values):
            self._queue(Report(self.client.new_report_id(), np.asarray(params), np.asarray(values), clips, failures,
                               tuple(pair_clips)))
        self._deliver()
        stats = self._call("tick", lambda: self.client.tick(iteration), {})
        if stats:  # no answer says nothing about a restart
            stats = self._after_stats(stats, iteration)
        out = {f"sampler/{k}": float(v) for k, v in stats.items()}
        out["sampler/learner_call_failures"] = float(self.failures)
        return out

    def _queue(self, report: "Report") -> None:
        self.unsent.append(report)
        while sum(len(r.values) for r in self.unsent) > MAX_UNSENT_PAIRS:
            dropped = self.unsent.popleft()
            self.pairs_lost += len(dropped.values)
            log.warning("sampler unreachable: %d value pairs dropped from the full queue (lost, counted)", len(dropped.values))

    def _deliver(self) -> None:
        """Send the queued reports, oldest first, until one cannot go (it stays queued)."""
        while self.unsent and time.monotonic() >= self.down_until:
            r = self.unsent[0]
            try:
                self.client.report(r.params, r.values, r.clips, r.failures, report_id=r.report_id,
                                   pair_clips=r.pair_clips)
            except ServiceUnavailable as exc:
                self.failures += 1
                self.down_until = time.monotonic() + RETRY_AFTER_S
                log.warning("sampler report failed (%s); %d pairs wait for it", exc, self.unsent_pairs())
                return
            except WireError as exc:  # refused for its content: sending it again cannot help
                self.failures += 1
                self.pairs_lost += len(r.values)
                log.warning("sampler refused a value report (%s); its %d pairs are lost (counted)", exc, len(r.values))
            else:
                self.pairs_delivered += len(r.values)
                self.taken_expected += len(r.values)
            self.unsent.popleft()

    def unsent_pairs(self) -> int:
        return sum(len(r.values) for r in self.unsent)

    def _after_stats(self, stats: dict[str, float], iteration: int) -> dict[str, float]:
        """Notice a sampler that restarted since the last answer (its start time changed): give it
        the checkpoint's state if that holds more than it came back with, and count the pairs it
        no longer holds."""
        started = stats.get("state/started_unix_s", 0.0)
        if self.started_seen and started != self.started_seen:
            self.restarts += 1
            own = bool(stats.get("state/restored", 0.0))
            if self.saved_state is not None and stats.get("vm/pairs_taken", 0.0) < pairs_taken_of(self.saved_state):
                # It came back with less than the last checkpoint: give it the checkpoint's state, tick again.
                log.warning("sampler restarted with less than the checkpoint's state; restoring the checkpoint's")
                if self._call("set_state", lambda: self.client.set_state(self.saved_state), False) is None:
                    self.restores += 1
                    stats = self._call("tick", lambda: self.client.tick(iteration), {}) or stats
            elif own:
                self.restores += 1
                log.warning("sampler restarted and restored its own state file")
        if stats.get("state/started_unix_s"):
            self.started_seen = stats["state/started_unix_s"]
        taken = stats.get("vm/pairs_taken")
        if taken is not None:
            if taken < self.taken_expected:  # a restart (or a resume) lost what it had not saved
                lost = int(self.taken_expected - taken)
                self.pairs_lost += lost
                log.warning("sampler holds %d value pairs fewer than it took (its state was older): lost, counted", lost)
            self.taken_expected = taken
        return stats

    def counters(self) -> dict[str, float]:
        """The learner-side sampler counters, as the run logs them under `faults/` and `sampler/`."""
        return {
            "faults/sampler_restarts": float(self.restarts),
            "faults/sampler_restores": float(self.restores),
            "faults/value_pairs_lost": float(self.pairs_lost),
            "faults/value_pairs_queued": float(self.unsent_pairs()),
            "sampler/value_pairs_delivered": float(self.pairs_delivered),
        }

    def state_dict(self) -> dict[str, int]:
        """Counters a resumed run continues from (checkpointed beside the sampler's own state)."""
        return {"failures": self.failures, "restarts": self.restarts, "restores": self.restores,
                "pairs_delivered": self.pairs_delivered, "pairs_lost": self.pairs_lost + self.unsent_pairs(),
                "taken_expected": int(self.taken_expected)}

    def load_state_dict(self, state: dict[str, Any], taken_since: float = 0.0) -> None:
        """Continue the counters of `state_dict()`. `taken_since`: the sampler's pairs taken as the
        learner last saw it (the progress file), when newer than the checkpoint: a sampler holding
        fewer at its first answer lost the difference."""
        self.failures = int(state.get("failures", 0))
        self.restarts = int(state.get("restarts", 0))
        self.restores = int(state.get("restores", 0))
        self.pairs_delivered = int(state.get("pairs_delivered", 0))
        self.pairs_lost = int(state.get("pairs_lost", 0))
        self.taken_expected = max(float(state.get("taken_expected", 0)), float(taken_since))

    def restore_at_start(self, state: dict[str, Any]) -> str:
        """A resumed run's sampler: keep the state it restored from its own file when that holds
        at least the checkpoint's pairs, else send it the checkpoint's. Returns what was done."""
        self.saved_state = state
        stats = self._call("stats", self.client.stats, {})
        own = stats.get("vm/pairs_taken", -1.0)
        if stats.get("state/restored") and own >= pairs_taken_of(state):
            return f"sampler kept its own state file ({int(own)} pairs taken; the checkpoint's has {pairs_taken_of(state)})"
        self.client.set_state(state)
        return f"sampler restored from the checkpoint ({pairs_taken_of(state)} pairs taken)"

    @contextlib.contextmanager
    def quick(self):
        """Calls inside give the sampler one try of `QUICK_TIMEOUT_S` (the stop path: a signal
        must end the run within seconds, whatever the sampler is doing)."""
        rpc = self.client.rpc
        saved = rpc.timeout_ms, rpc.retries
        rpc.timeout_ms, rpc.retries = int(QUICK_TIMEOUT_S * 1000), 1
        try:
            yield self
        finally:
            rpc.timeout_ms, rpc.retries = saved

    def flush(self) -> None:
        """At stop: deliver what is queued if the sampler answers now; what stays is counted lost
        (`state_dict` adds it)."""
        self._deliver()

    def state(self) -> dict[str, Any] | None:
        return self._call("get_state", self.client.get_state, None)

    def plot(self, path: Path) -> None:
        """Write the Vm map PNG (Won & Lee 2019, Figure 6) from the service's current state; a fixed
        body has no map, and its state is not fetched."""
        from sampler.plot import has_map, plot_state  # lazy: heavy (matplotlib), only when plotting

        params = self.config.plot_params or None
        try:
            if not has_map(self.space, params):
                return
            state = self.state()
            if state is not None:
                plot_state(state, self.space, path, params=params)
        except Exception as exc:  # noqa: BLE001 - a plot must never stop training
            log.warning("could not plot the marginal value map: %s", exc)

    def stop(self) -> None:
        self.client.close()
        if self.stop_event is not None and self.thread is not None:
            self.stop_event.set()
            self.thread.join(timeout=5)
        if self.ray_handle is not None:
            import ray  # lazy: heavy (ray), only in the Ray modes

            try:
                ray.get(self.ray_handle.stop.remote(), timeout=10)
            except Exception:  # noqa: BLE001 - already gone
                pass
            ray.kill(self.ray_handle, no_restart=True)
