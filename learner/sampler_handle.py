"""The learner's handle on the sampler service: starts it (a Ray actor in cluster and local
modes, a thread in serial mode), talks to it through the same ZeroMQ client as the actors, and
stops it. A sampler that does not answer costs the learner its metrics for that iteration,
never the run."""

from __future__ import annotations

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

RETRY_AFTER_S = 10.0
"""After the sampler failed to answer, the learner leaves it alone this long."""
LEARNER_TIMEOUT_S = 3.0
"""A tick may fit Vm and refill the buffer (tenths of a second; more on a loaded machine)."""


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
    pairs_seen: float = 0.0
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
                        failures: tuple[list[str], list[float]] = ([], [])) -> dict[str, float]:
        """Report the value pairs, `clips` (the training segments per clip since the last call:
        ids, segments, tracked) and `failures` (clip ids and clip times of the failed segments,
        sent only when the sampler keeps time bins), then tick. Only clips the sampler draws are
        sent; the sampler checks every time against its clip."""
        known = {cid for cid, _ in self.clips}
        keep = [i for i, cid in enumerate(clips[0]) if cid in known]
        clips = tuple([part[i] for i in keep] for part in clips)
        keep = [i for i, cid in enumerate(failures[0]) if cid in known] if self.config.time_bin_s > 0 else []
        failures = tuple([part[i] for i in keep] for part in failures)
        self._call("report", lambda: self.client.report(params, values, clips, failures), None)
        stats = self._call("tick", lambda: self.client.tick(iteration), {})
        restarted = False
        if stats:  # no answer says nothing about a restart
            seen = stats.get("vm/pairs_seen", 0.0)
            restarted = seen < self.pairs_seen  # a live sampler's count never decreases
            self.pairs_seen = seen if restarted else max(self.pairs_seen, seen)
        if restarted and self.saved_state is not None:
            # A restarted sampler came back empty: give it the checkpointed state, then tick again.
            log.warning("sampler restarted without its state; restoring the last checkpoint's")
            if self._call("set_state", lambda: self.client.set_state(self.saved_state), False) is None:
                self.restores += 1
                stats = self._call("tick", lambda: self.client.tick(iteration), {})
        out = {f"sampler/{k}": float(v) for k, v in stats.items()}
        out["sampler/learner_call_failures"] = float(self.failures)
        return out

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
