"""Configuration of the rollout actors."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
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
