"""Heartbeat-based health of the rollout actors, as the learner sees it.

Every unroll and heartbeat refreshes an actor's last-seen time (`LearnerTransport.last_seen`);
only a valid message from a configured actor id does, so a hostile or mistaken peer cannot add a
phantom actor to these counts (`rejected/unknown_actor` counts it instead).
An actor silent for `stall_timeout_s` is declared stalled: counted once, logged, and excluded
from the alive count (its late unrolls, if it ever sends them, are stale and dropped by the
policy-lag rule). When it sends again it is re-admitted, counted and logged. The learner never
waits on a particular actor, so a stall costs throughput, never progress.
"""

from __future__ import annotations

import time
from typing import Callable


class HealthMonitor:
    def __init__(self, last_seen: dict[int, float], stall_timeout_s: float, say: Callable[[str], None]):
        self.last_seen = last_seen
        self.stall_timeout_s = stall_timeout_s
        self.say = say
        self.stalled: set[int] = set()
        self.stalls = 0
        self.readmissions = 0

    def check(self, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        for actor_id, seen in list(self.last_seen.items()):
            silent = now - seen
            if silent > self.stall_timeout_s and actor_id not in self.stalled:
                self.stalled.add(actor_id)
                self.stalls += 1
                self.say(f"[morphmimic] actor {actor_id} silent for {silent:.1f} s: marked stalled and excluded")
            elif silent <= self.stall_timeout_s and actor_id in self.stalled:
                self.stalled.discard(actor_id)
                self.readmissions += 1
                self.say(f"[morphmimic] actor {actor_id} is sending again: re-admitted")

    def alive(self) -> int:
        return len(self.last_seen) - len(self.stalled)

    def state_dict(self) -> dict[str, int]:
        """The cumulative counts a resumed run continues from (who is stalled now is not kept)."""
        return {"stalls": self.stalls, "readmissions": self.readmissions}

    def load_state_dict(self, state: dict[str, int]) -> None:
        self.stalls = int(state.get("stalls", 0))
        self.readmissions = int(state.get("readmissions", 0))

    def metrics(self) -> dict[str, float]:
        return {
            "health/actors_reporting": float(self.alive()),
            "health/actors_stalled": float(len(self.stalled)),
            "health/stalls": float(self.stalls),
            "health/readmissions": float(self.readmissions),
        }
