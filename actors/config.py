"""Configuration of the rollout actors."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from common.config_limits import Limit, above, at_least, between, check_limits, validated


@dataclass(frozen=True)
@validated
class ActorConfig:
    num_actors: int = 2
    """Rollout actors (one process each in Ray modes)."""
    envs_per_actor: int = 8
    """Environments each actor steps in lockstep, with one batched policy forward per step."""
    unroll_length: int = 32
    """Control steps per unroll message (T); a message carries T x envs_per_actor transitions."""
    torch_threads: int = 1
    """Torch intra-op threads per actor: 1 keeps actors from fighting over cores."""
    weights_timeout_s: float = 2.0
    """How long an actor waits for a weights snapshot reply before asking again."""
    sampler_timeout_s: float = 2.0
    """How long an actor waits for a sampler draw before retrying (Lazy Pirate)."""
    sampler_retries: int = 2
    """Tries per draw before degrading to the previous draws."""
    draw_batch: int = 32
    """Episode parameter draws fetched from the sampler per request."""
    heartbeat_s: float = 2.0
    """An actor sends a heartbeat when it has sent nothing for this long."""
    num_cpus: float = 1.0
    """Ray CPUs reserved per rollout actor."""
    seq_ledger_dir: str = ""
    """Directory for durable unroll sequence numbers (see actors/seq_ledger.py); empty: the run
    directory's `ledger/` when every node is on this machine, else none."""

    FLAG_PREFIX: ClassVar[str] = "actors"
    LIMITS: ClassVar[dict[str, Limit]] = {
        "num_actors": between(1, 4096, integer=True), "envs_per_actor": between(1, 4096, integer=True),
        "unroll_length": between(1, 100_000, integer=True), "torch_threads": at_least(1), "weights_timeout_s": above(0),
        "sampler_timeout_s": above(0), "sampler_retries": at_least(0), "draw_batch": at_least(1), "heartbeat_s": above(0),
        "num_cpus": between(0, 1024, lo_open=True),
    }
    """Allowed values of the numeric fields (`common.config_limits`)."""

    def validate(self) -> None:
        """ValueError naming the first value outside what is allowed."""
        check_limits(self)

