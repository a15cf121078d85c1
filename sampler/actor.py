"""Where the sampler service runs: a Ray actor (cluster and local modes) or a thread (serial mode).

Both run the same `SamplerService.serve` loop on a background thread; clients talk to it only
over ZeroMQ, so the learner and actors use the same code in every mode.

    # cluster / local mode
    Remote = ray.remote(num_cpus=0.5, max_restarts=-1)(SamplerActor)
    handle = Remote.remote(cfg, space, clips)
    endpoint = ray.get(handle.endpoint.remote())

    # serial mode
    service, thread, stop = start_in_thread(cfg, space, clips)
    ...; stop.set(); thread.join()
"""

from __future__ import annotations

import dataclasses
import threading
from typing import Mapping, Sequence

from common.curve_keys import RunKeys
from common.params import ParamSpace
from sampler.config import SamplerConfig
from sampler.service import SamplerService


def start_in_thread(config: SamplerConfig, space: ParamSpace, clips: Sequence[tuple[str, str]] | None = None,
                    address: str | None = None, keys: RunKeys | None = None, durations: Mapping[str, float] | None = None,
                    ) -> tuple[SamplerService, threading.Thread, threading.Event]:
    """Bind the service here and serve it on a daemon thread. Stop with `stop_event.set()` then
    `thread.join()`; the thread closes the socket on its way out.

    NOTE: the socket is created on the calling thread and used only by the serving thread from
    then on; ZeroMQ allows moving a socket across threads behind a memory barrier, which
    `Thread.start` provides."""
    service = SamplerService(config, space, clips, address=address, keys=keys, durations=durations)
    stop_event = threading.Event()
    thread = threading.Thread(target=service.serve, args=(stop_event,), name="sampler-service", daemon=True)
    thread.start()
    return service, thread, stop_event


class SamplerActor:
    """Ray actor body: wrap it with `ray.remote(...)` where the placement options are known.

    `config.host == "auto"` binds this node's IP (`ray.util.get_node_ip_address()`), which
    clients on other nodes can reach; the default 127.0.0.1 serves this machine only."""

    def __init__(self, config: SamplerConfig, space: ParamSpace, clips: Sequence[tuple[str, str]] | None = None,
                 keys: RunKeys | None = None, durations: Mapping[str, float] | None = None):
        if config.host == "auto":
            import ray  # lazy: heavy (ray), only a Ray actor resolves "auto"; serial mode never needs ray

            config = dataclasses.replace(config, host=ray.util.get_node_ip_address())
        self.service, self._thread, self._stop = start_in_thread(config, space, clips, keys=keys, durations=durations)

    def endpoint(self) -> str:
        return self.service.endpoint

    def alive(self) -> bool:
        """False once the serving thread has ended (stopped or crashed)."""
        return self._thread.is_alive()

    def stop(self) -> None:
        """Stop serving and release the port (the actor itself stays until killed)."""
        self._stop.set()
        self._thread.join(timeout=5.0)
