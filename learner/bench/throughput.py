"""`morphmimic bench throughput`: is the distributed pipeline as fast as plain simulation?

In one run, on the same task, policy size and environments per actor, `--rounds` rounds of:
1. end to end: a local-mode training run (Ray actors -> ZeroMQ -> PPO learner on the same
   cores), timed after a warm-up of a few iterations. At every iteration the bench keeps the
   policy the learner publishes and the sampler's state (its draw buffer, position and RNG);
2. pure simulation: one process steps `envs_per_actor` environments with one batched policy
   forward per control step (exactly `RolloutWorker.collect`, no sockets, no learner), built
   with actor 0's seeds and drawing its shapes and clips from a `ShapeSampler` of the run's
   configuration and seed, in a fresh process at the actors' scheduling priority (Ray runs
   them at niceness 15). It replays the run: per iteration, the policy the actors ran and the
   sampler state they drew from, for one actor's share of the iteration's steps; the warm-up
   iterations untimed (a process's first episodes of each clip and shape fill its caches),
   then the timed ones.

So both phases see the same environments, the same shapes and clips and the same episode mix
(an untrained policy falls within tens of steps, and resets then dominate collection: a pure
phase on another policy or other shapes measured 743 to 1,179 steps/s from run to run), and
compete alike with whatever else runs on the machine.

Reported: end-to-end environment steps/s received by the learner, per simulating core (one core
per rollout actor), as a ratio of pure simulation, over all rounds and per round (the spread is
the bench's own noise: background load, the policy's early learning); the learner's share of
wall time; transport bytes/s. Absolute rates swing 10-25% between runs on shared machines:
read the ratio.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import ClassVar

import torch

from actors.draws import DrawCache
from actors.rollout import RolloutWorker
from common import wire
from common.config_limits import Limit, at_least, check_limits, validated
from common.tasks.registry import task_clip_durations, task_clips, task_space
from learner.cli_options import parse_options
from learner.config import RunConfig
from learner.presets import PRESETS, check_presets
from sampler.shape_sampler import ShapeSampler


@dataclass
class Round:
    """One end-to-end run and what its pure-simulation replay needs."""

    marks: list[tuple[float, dict]] = field(default_factory=list)
    """(time, metrics) at the end of every iteration."""
    weights: list[wire.WeightsMsg] = field(default_factory=list)
    """The policy published at the end of every iteration (what actors run next)."""
    sampler_states: list[dict | None] = field(default_factory=list)
    """The sampler's state at the end of every iteration (None: it did not answer)."""
    collected: list[float] = field(default_factory=list)
    """Environment steps the actors had collected at the end of every iteration."""
    actor_niceness: int | None = None
    """The scheduling niceness of actor 0's process (Ray starts workers at 15)."""


def end_to_end(cfg: RunConfig, warmup_iterations: int) -> tuple[dict[str, float], Round]:
    from learner.train import train  # lazy: heavy (Ray, TensorBoard), only for the end-to-end runs

    rec = Round()

    def on_iteration(run, metrics: dict) -> None:
        rec.marks.append((time.perf_counter(), dict(metrics)))
        rec.weights.append(run.learner.weights_msg())
        rec.sampler_states.append(run.sampler.state())
        stats = run.pool.stats()  # the actors' own counters (one call each)
        rec.collected.append(float(sum(s["env_steps"] for s in stats)) if stats else float("nan"))
        if rec.actor_niceness is None and stats:
            rec.actor_niceness = os.getpriority(os.PRIO_PROCESS, stats[0]["pid"])

    train(cfg, on_iteration=on_iteration)
    if len(rec.marks) <= warmup_iterations + 1:
        raise SystemExit(f"only {len(rec.marks)} iterations ran; raise --iterations")
    (t0, m0), (t1, m1) = rec.marks[warmup_iterations], rec.marks[-1]
    wall = t1 - t0
    update_s = sum(m["stats/update_s"] for _, m in rec.marks[warmup_iterations + 1 :])
    return {
        "steps": m1["wire/steps_received"] - m0["wire/steps_received"],
        "steps_per_s": (m1["wire/steps_received"] - m0["wire/steps_received"]) / wall,
        "collected": rec.collected[-1] - rec.collected[warmup_iterations],
        "trained_steps_per_s": (m1["stats/env_steps"] - m0["stats/env_steps"]) / wall,
        "learner_share": update_s / wall,
        "update_s": update_s,
        "bytes": m1["wire/bytes_received"] - m0["wire/bytes_received"],
        "stale": m1["wire/stale_unrolls"] - m0["wire/stale_unrolls"],
        "trained_steps": m1["stats/env_steps"] - m0["stats/env_steps"],
        "episodes": m1["charts/episodes"] - m0["charts/episodes"],
        "wall_s": wall,
        "timed_iterations": len(rec.marks) - 1 - warmup_iterations,
        "actor_niceness": rec.actor_niceness,
    }, rec


def pure_simulation(cfg: RunConfig, rec: Round, warmup_iterations: int) -> dict[str, float]:
    """Steps/s of one process doing what actor 0 does, minus every socket, replaying the timed
    iterations of `rec`: per iteration, the policy and sampler state of its start and one
    actor's share of its steps (whole unrolls)."""
    torch.set_num_threads(cfg.actors.torch_threads)
    space = task_space(cfg.task)
    # The service's sampler as `learner.train` configures it; actor 0's seeds (`actor_pool`).
    durations = task_clip_durations(cfg.task) if cfg.sampler.time_bin_s > 0 else None
    sampler = ShapeSampler(dataclasses.replace(cfg.sampler, seed=cfg.sampler.seed + cfg.seed), space, task_clips(cfg.task),
                           durations)
    actor_seed = cfg.seed + 1000
    draws = DrawCache(sampler.draw_episodes, space, cfg.actors.draw_batch, seed=actor_seed + 1)
    worker = RolloutWorker(0, cfg.task, cfg.policy, cfg.actors, draws, seed=actor_seed)

    def load(i: int) -> None:
        worker.set_weights(rec.weights[i])
        if rec.sampler_states[i] is not None:
            sampler.load_state_dict(rec.sampler_states[i])

    per_unroll = cfg.actors.unroll_length * cfg.actors.envs_per_actor
    unrolls = max(1, math.ceil(cfg.steps_per_iteration / cfg.actors.num_actors / per_unroll))
    replay = range(warmup_iterations, len(rec.marks) - 1)
    # NOTE: warm-up, untimed, as long as the actors' before the timed window: a process fills
    # caches on its first episodes of each clip and shape (the executor's pure phase ran at
    # 0.6x the actors' rate after a one-unroll warm-up).
    for i in range(warmup_iterations) if warmup_iterations else [replay[0]]:
        load(i)
        for _ in range(unrolls if warmup_iterations else 1):
            worker.collect()
    seconds, steps, episodes = 0.0, 0, 0
    for i in replay:
        start, before = time.perf_counter(), worker.env_steps
        load(i)
        for _ in range(unrolls):
            episodes += len(worker.collect().episode_lengths)
        seconds += time.perf_counter() - start
        steps += worker.env_steps - before
    return {"steps": steps, "seconds": seconds, "steps_per_s": steps / seconds, "episodes": episodes,
            "niceness": os.nice(0)}


def pure_simulation_like_an_actor(cfg: RunConfig, rec: Round, warmup_iterations: int) -> dict[str, float]:
    """`pure_simulation` in a fresh Python process at the actors' scheduling priority.

    NOTE: Ray runs actors at niceness 15; run at 0 in this process, the pure phase took the CPU
    from any background load the actors had to share it with. A plain subprocess rather than
    `multiprocessing`: its spawn start method re-runs the calling script's top level."""
    with tempfile.TemporaryDirectory() as tmp:
        args, result = os.path.join(tmp, "args.pkl"), os.path.join(tmp, "result.pkl")
        with open(args, "wb") as f:
            pickle.dump((cfg, rec, warmup_iterations), f)
        code = "import sys; from learner.bench.throughput import _pure_child; _pure_child(sys.argv[1], sys.argv[2])"
        subprocess.run([sys.executable, "-c", code, args, result], check=True)
        with open(result, "rb") as f:
            return pickle.load(f)


def _pure_child(args_path: str, result_path: str) -> None:
    with open(args_path, "rb") as f:
        cfg, rec, warmup_iterations = pickle.load(f)
    if rec.actor_niceness is not None and rec.actor_niceness > os.nice(0):
        os.nice(rec.actor_niceness - os.nice(0))
    out = pure_simulation(cfg, rec, warmup_iterations)
    with open(result_path, "wb") as f:
        pickle.dump(out, f)


PROG = "morphmimic bench throughput"


@validated
@dataclass
class ThroughputBenchOptions:
    preset: str = "reach"
    """Training preset whose task and policy are measured."""
    actors: int = 2
    """Rollout actors (simulating cores)."""
    envs_per_actor: int = 8
    """Environments per rollout actor."""
    rounds: int = 3
    """End-to-end runs, each followed by its pure-simulation replay."""
    iterations: int = 8
    """Training iterations per end-to-end run."""
    warmup: int = 3
    """Iterations excluded from the timing."""
    curve: bool = True
    """CURVE on the sockets, as in training (`--no-curve`: plain sockets, to see what authentication costs: `morphmimic bench curve`)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"actors": at_least(1), "envs_per_actor": at_least(1), "rounds": at_least(1), "iterations": at_least(1), "warmup": at_least(0)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_presets("--preset", [self.preset])
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(ThroughputBenchOptions, argv, prog=PROG, description=__doc__)

    base = PRESETS[args.preset][1]
    e2e_rounds: list[dict[str, float]] = []
    pure_rounds: list[dict[str, float]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            cfg = dataclasses.replace(
                base, name=f"bench-{r}", runs_dir=tmp, mode="local", quiet=True, resume="never", curve=args.curve,
                max_iterations=args.iterations, total_env_steps=10**9, checkpoint_every=10**6,
                actors=dataclasses.replace(base.actors, num_actors=args.actors, envs_per_actor=args.envs_per_actor),
            )
            e2e, rec = end_to_end(cfg, args.warmup)
            e2e_rounds.append(e2e)
            pure_rounds.append(pure_simulation_like_an_actor(cfg, rec, args.warmup))
    wall = sum(e["wall_s"] for e in e2e_rounds)
    e2e_rate = sum(e["steps"] for e in e2e_rounds) / wall
    trained_rate = sum(e["trained_steps_per_s"] * e["wall_s"] for e in e2e_rounds) / wall
    pure = sum(p["steps"] for p in pure_rounds) / sum(p["seconds"] for p in pure_rounds)
    per_core = e2e_rate / args.actors
    round_ratios = [e["steps_per_s"] / args.actors / p["steps_per_s"] for e, p in zip(e2e_rounds, pure_rounds)]
    timed = sum(e["timed_iterations"] for e in e2e_rounds)
    print(f"task {cfg.task.name}, {args.actors} actors x {args.envs_per_actor} envs, policy {cfg.policy.hidden}, "
          f"{'CURVE' if cfg.curve else 'plain'} sockets, "
          f"{cfg.steps_per_iteration} steps/iteration, {args.rounds} rounds, {timed} timed iterations ({wall:.0f} s)")
    nice = sorted({p["niceness"] for p in pure_rounds})
    print(f"  pure simulation, one process        {pure:9.0f} steps/s  (same policies, shapes and clips as end to end; "
          f"niceness {'/'.join(map(str, nice))}, the actors' {e2e_rounds[-1]['actor_niceness']})")
    print(f"  end to end, received by the learner {e2e_rate:9.0f} steps/s  ({per_core:.0f} per simulating core)")
    print(f"  end to end, collected by the actors {sum(e['collected'] for e in e2e_rounds) / wall:9.0f} steps/s  "
          "(what they stepped; the learner's count differs by what sat in the queues)")
    print(f"  end to end, trained on (fresh)      {trained_rate:9.0f} steps/s  "
          f"({sum(e['stale'] for e in e2e_rounds):.0f} stale unrolls dropped)")
    print(f"  ratio per simulating core           {per_core / pure:9.2f}")
    print(f"  learner share of wall time          {100 * sum(e['update_s'] for e in e2e_rounds) / wall:8.0f} %")
    print(f"  transport                           {sum(e['bytes'] for e in e2e_rounds) / wall / 1e6:9.2f} MB/s")
    e2e_eps = sum(e["episodes"] for e in e2e_rounds) / max(sum(e["trained_steps"] for e in e2e_rounds), 1)
    pure_eps = sum(p["episodes"] for p in pure_rounds) / sum(p["steps"] for p in pure_rounds)
    print(f"  episodes ended per 1000 steps       {1000 * e2e_eps:9.1f} end to end, {1000 * pure_eps:.1f} pure (the reset share)")
    print(f"  per round: ratio                    {' '.join(f'{x:.2f}' for x in round_ratios)}  "
          f"(median {statistics.median(round_ratios):.2f}, spread {max(round_ratios) - min(round_ratios):.2f})")
    row = lambda values, fmt: " ".join(format(v, fmt) for v in values)  # noqa: E731
    print(f"  per round: pure simulation          {row((p['steps_per_s'] for p in pure_rounds), '.0f')} steps/s")
    print(f"  per round: end to end per core      {row((e['steps_per_s'] / args.actors for e in e2e_rounds), '.0f')} steps/s")
    print(f"  per round: learner share            {row((100 * e['learner_share'] for e in e2e_rounds), '.0f')} %")
    return 0
