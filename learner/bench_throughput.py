"""`morphmimic bench throughput`: is the distributed pipeline as fast as plain simulation?

In one run, on the same task, policy size and environments per actor:
1. pure simulation: one process steps `envs_per_actor` environments with one batched policy
   forward per control step (exactly `RolloutWorker.collect`, no sockets, no learner);
2. end to end: a local-mode training run (Ray actors -> ZeroMQ -> PPO learner on the same
   cores), timed after a warm-up of a few iterations.

Reported: end-to-end environment steps/s received by the learner, per simulating core (one core
per rollout actor), as a ratio of pure simulation; the learner's share of wall time; transport
bytes/s. Absolute rates swing 10-25% between runs on shared machines: read the ratio.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time

import numpy as np
import torch

from actors.rollout import RolloutWorker
from common.tasks.registry import task_space
from learner.config import RunConfig
from learner.presets import PRESETS


def pure_simulation(cfg: RunConfig, seconds: float) -> float:
    """Steps/s of one process doing what an actor does, minus every socket."""
    torch.set_num_threads(1)
    space = task_space(cfg.task)
    rng = np.random.default_rng(0)
    worker = RolloutWorker(0, cfg.task, cfg.policy, cfg.actors, lambda: (space.uniform(rng, 1)[0], None), seed=0)
    worker.collect()  # warm-up
    start, steps = time.perf_counter(), worker.env_steps
    while time.perf_counter() - start < seconds:
        worker.collect()
    return (worker.env_steps - steps) / (time.perf_counter() - start)


def end_to_end(cfg: RunConfig, warmup_iterations: int) -> dict[str, float]:
    from learner.train import train

    marks: list[tuple[float, dict]] = []
    train(cfg, on_iteration=lambda run, m: marks.append((time.perf_counter(), dict(m))))
    if len(marks) <= warmup_iterations + 1:
        raise SystemExit(f"only {len(marks)} iterations ran; raise --iterations")
    (t0, m0), (t1, m1) = marks[warmup_iterations], marks[-1]
    wall = t1 - t0
    update_s = sum(m["stats/update_s"] for _, m in marks[warmup_iterations + 1 :])
    return {
        "steps_per_s": (m1["wire/steps_received"] - m0["wire/steps_received"]) / wall,
        "trained_steps_per_s": (m1["stats/env_steps"] - m0["stats/env_steps"]) / wall,
        "learner_share": update_s / wall,
        "bytes_per_s": (m1["wire/bytes_received"] - m0["wire/bytes_received"]) / wall,
        "stale": m1["wire/stale_unrolls"] - m0["wire/stale_unrolls"],
        "wall_s": wall,
    }


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="morphmimic bench throughput", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="reach", help="training preset whose task and policy are measured")
    parser.add_argument("--actors", type=int, default=2, help="rollout actors (simulating cores)")
    parser.add_argument("--envs-per-actor", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=14, help="training iterations end to end")
    parser.add_argument("--warmup", type=int, default=3, help="iterations excluded from the timing")
    parser.add_argument("--pure-seconds", type=float, default=15.0)
    args = parser.parse_args(argv)

    base = PRESETS[args.preset][1]
    with tempfile.TemporaryDirectory() as tmp:
        cfg = dataclasses.replace(
            base, name="bench", runs_dir=tmp, mode="local", quiet=True, resume="never",
            max_iterations=args.iterations, total_env_steps=10**9, checkpoint_every=10**6,
            actors=dataclasses.replace(base.actors, num_actors=args.actors, envs_per_actor=args.envs_per_actor),
        )
        pure = pure_simulation(cfg, args.pure_seconds)
        e2e = end_to_end(cfg, args.warmup)
    per_core = e2e["steps_per_s"] / args.actors
    print(f"task {cfg.task.name}, {args.actors} actors x {args.envs_per_actor} envs, policy {cfg.policy.hidden}, "
          f"{cfg.steps_per_iteration} steps/iteration, {args.iterations - args.warmup} timed iterations ({e2e['wall_s']:.0f} s)")
    print(f"  pure simulation, one process        {pure:9.0f} steps/s")
    print(f"  end to end, received by the learner {e2e['steps_per_s']:9.0f} steps/s  ({per_core:.0f} per simulating core)")
    print(f"  end to end, trained on (fresh)      {e2e['trained_steps_per_s']:9.0f} steps/s  ({e2e['stale']:.0f} stale unrolls dropped)")
    print(f"  ratio per simulating core           {per_core / pure:9.2f}")
    print(f"  learner share of wall time          {100 * e2e['learner_share']:8.0f} %")
    print(f"  transport                           {e2e['bytes_per_s'] / 1e6:9.2f} MB/s")
    return 0


