"""Episode parameter draws from the sampler service, with the documented degraded mode.

A draw is an episode's task/shape parameters, its clip id and its start time in the clip (the
last two None when the sampler gives none: the environment then draws them). Draws are fetched
in batches. When the sampler does not answer (outage, restart), the actor
keeps going on its last batch of draws, cycling through them, and counts each fetch that
failed; when the sampler answers again, fresh draws resume. Before the first successful
fetch, draws are uniform over the task's parameter box (the `k = 0` baseline).
"""

from __future__ import annotations

import logging
from typing import Callable

import numpy as np

from common.params import ParamSpace
from common.rpc import ServiceUnavailable
from common.wire import WireError

log = logging.getLogger(__name__)

FetchFn = Callable[[int], tuple[np.ndarray, list[str], list[float]]]
"""n draws: parameters `[n, d]`, n clip ids (or none), n start times in s (or none)."""


class DrawCache:
    def __init__(self, fetch: FetchFn | None, space: ParamSpace, batch: int, seed: int = 0):
        self.fetch, self.space, self.batch = fetch, space, batch
        self.rng = np.random.default_rng(seed)
        self.params: np.ndarray | None = None
        self.clip_ids: list[str] = []
        self.start_s: list[float] = []
        self.cursor = 0
        self.outages = 0
        """Fetches that failed; each one means draws were reused instead of fresh."""
        self.in_outage = False

    def _refill(self) -> None:
        if self.fetch is not None:
            try:
                params, clip_ids, start_s = self.fetch(self.batch)
                self.params = np.asarray(params, np.float64)
                self.clip_ids = list(clip_ids)
                # NOTE: a start is only meaningful with its clip: the wire holds a reply's lists to
                # one entry per draw or none, and starts without clips are not used.
                self.start_s = [float(t) for t in start_s] if len(start_s) == len(self.clip_ids) else []
                if self.in_outage:
                    log.warning("sampler is back after %d failed fetches", self.outages)
                self.in_outage = False
                self.cursor = 0
                return
            except (ServiceUnavailable, WireError) as exc:
                self.outages += 1
                if not self.in_outage:
                    log.warning("sampler unavailable (%s): reusing the last draws", exc)
                self.in_outage = True
        if self.params is None:
            self.params = self.space.uniform(self.rng, self.batch)
            self.clip_ids = []
            self.start_s = []
        self.cursor = 0

    def __call__(self) -> tuple[np.ndarray, str | None, float | None]:
        """The next draw: (parameters, clip id or None, start time in s or None)."""
        if self.params is None or self.cursor >= len(self.params):
            self._refill()
        i = self.cursor
        self.cursor += 1
        clip = self.clip_ids[i] if i < len(self.clip_ids) else None
        start = self.start_s[i] if i < len(self.start_s) else None
        return self.params[i], clip, start
