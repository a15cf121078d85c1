"""Assembles each PPO batch from the unrolls that stream in."""

from __future__ import annotations

import time

from learner.config import RunConfig
from learner.run_log import RunLog
from learner.signals import StopFlag
from learner.transport import LearnerTransport

WAIT_WARN_S = 15.0
"""Say so on the console when no usable unroll arrived for this long."""


class Collector:
    """Gathers each iteration's batch: exactly `steps_per_iteration` transitions (rounded up to
    whole unrolls), oldest first. Unrolls that arrive beyond that wait for the next iteration,
    where they are used if still within the allowed policy lag, else dropped and counted."""

    def __init__(self, transport: LearnerTransport, pool, cfg: RunConfig, stop: StopFlag, serial: bool, out: RunLog):
        self.transport, self.pool, self.cfg, self.stop, self.serial, self.out = transport, pool, cfg, stop, serial, out
        self.pending: list = []

    def _fresh(self, policy_version: int) -> None:
        with self.stop.held():
            keep = [u for u in self.pending if policy_version - u.policy_version <= self.cfg.max_policy_lag]
            self.transport.counters["stale_unrolls"] += len(self.pending) - len(keep)
            self.pending = keep

    def next_batch(self, policy_version: int) -> list | None:
        """The next batch, or None if a stop was requested first."""
        self._fresh(policy_version)
        last_data = time.monotonic()
        while sum(u.rewards.size for u in self.pending) < self.cfg.steps_per_iteration:
            if self.stop:
                return None
            self.pool.pump()
            with self.stop.held():  # counted received, then pending: one step under a second signal
                got = self.transport.receive(0 if self.serial else 50, policy_version, self.cfg.max_policy_lag)
                self.pending.extend(got)
            if got:
                last_data = time.monotonic()
            elif time.monotonic() - last_data > WAIT_WARN_S:
                alive = self.pool.alive()
                self.out.line(f"[morphmimic] waiting for unrolls: {alive} rollout actor(s) alive, counters {dict(self.transport.counters)}")
                if alive == 0:
                    raise RuntimeError("every rollout actor is gone; stopping (see the log above for why)")
                last_data = time.monotonic()
        batch, steps = [], 0
        with self.stop.held():
            while steps < self.cfg.steps_per_iteration:
                u = self.pending.pop(0)
                batch.append(u)
                steps += u.rewards.size
            self.transport.counters["unrolls_trained"] += len(batch)
        return batch
