"""`morphmimic bench scaling`: fresh samples per second against rollout actors and learner replicas.

The tool a cluster user runs to size a deployment. It starts the local test cluster of
`morphmimic local-cluster` with as many worker nodes as the largest actor count (one rollout actor
per node, one CPU each: the "simulated nodes") and a head that may host the extra learner
replicas, then runs the same training job on it for each actor count x replica count at a fixed
step budget (`--iterations` PPO iterations of the preset's size), timed after `--warmup`
iterations. Every run is measured as `morphmimic bench throughput` measures its end-to-end phase.

Reported per run: fresh samples per second (environment steps that went into PPO updates, per
wall second), samples per second received, the learner's share of wall time (the update, with
its replicas, over the iteration) and the stale unrolls dropped. Written to `--out`:
`scaling.json`, `scaling.md` and `scaling.png` (fresh samples/s and learner share against
actors, one line per replica count).

On a machine with fewer cores than actors + learners, every added process takes time from the
others and the curve flattens early: that is the measurement, not a defect. Read the curve of a
real cluster from a run on it (`--address` of a running cluster with the `morphmimic_rollout`
and `morphmimic_learner` resources; see deploy/README.md).
"""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from common.config_limits import Limit, at_least, check_limits, validated
from learner.bench.throughput import end_to_end
from learner.cli_options import CommaInts, parse_options, refuse
from learner.cluster import start_test_cluster as start
from learner.config import LearnerConfig, RunConfig
from learner.presets import PRESETS, check_presets


def run_config(base: RunConfig, address: str, runs_dir: str, actors: int, replicas: int, envs_per_actor: int,
               iterations: int, learner_threads: int) -> RunConfig:
    """The job for one point of the curve: `actors` rollout actors and `replicas` learners on the cluster at `address`."""
    return dataclasses.replace(
        base, name=f"scaling-a{actors}-r{replicas}", runs_dir=runs_dir, mode="cluster", ray_address=address, quiet=True,
        resume="never", max_iterations=iterations, total_env_steps=10**9, checkpoint_every=10**6,
        learner=LearnerConfig(replicas=replicas, threads=learner_threads),
        actors=dataclasses.replace(base.actors, num_actors=actors, envs_per_actor=envs_per_actor),
    )


def measure(base: RunConfig, address: str, actors: list[int], replicas: list[int], envs_per_actor: int,
            iterations: int, warmup: int, learner_threads: int) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for a in actors:
            for r in replicas:
                cfg = run_config(base, address, tmp, a, r, envs_per_actor, iterations, learner_threads)
                e2e, _ = end_to_end(cfg, warmup)
                rows.append({"actors": a, "replicas": r, "fresh_steps_per_s": e2e["trained_steps_per_s"],
                             "received_steps_per_s": e2e["steps_per_s"], "learner_share": e2e["learner_share"],
                             "stale_unrolls": e2e["stale"], "timed_iterations": e2e["timed_iterations"],
                             "wall_s": e2e["wall_s"]})
                print(f"  actors {a:2d}  replicas {r}  fresh {e2e['trained_steps_per_s']:7.0f} steps/s  "
                      f"received {e2e['steps_per_s']:7.0f}  learner {100 * e2e['learner_share']:3.0f}%  "
                      f"stale unrolls {e2e['stale']:.0f}", flush=True)
    return rows


def write(out: Path, meta: dict, rows: list[dict]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "scaling.json").write_text(json.dumps({**meta, "rows": rows}, indent=2) + "\n")
    lines = [f"# Scaling: {meta['preset']} on {meta['cpus']} cores", "",
             f"`{meta['command']}`", "",
             (f"{meta['iterations']} iterations of {meta['steps_per_iteration']} steps per run, the first {meta['warmup']} "
              f"untimed; {meta['envs_per_actor']} environments per actor; policy {meta['hidden']}; "
              f"{meta['learner_threads']} torch thread(s) per learner."), "",
             "| actors | learner replicas | fresh samples/s | received samples/s | learner share % | stale unrolls |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {r['actors']} | {r['replicas']} | {r['fresh_steps_per_s']:.0f} | {r['received_steps_per_s']:.0f} | "
              f"{100 * r['learner_share']:.0f} | {r['stale_unrolls']:.0f} |" for r in rows]
    (out / "scaling.md").write_text("\n".join(lines) + "\n")
    _plot(out / "scaling.png", meta, rows)


def _plot(path: Path, meta: dict, rows: list[dict]) -> None:
    import matplotlib  # lazy: heavy (matplotlib), only when plotting

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: heavy (matplotlib), only when plotting

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    for r in sorted({row["replicas"] for row in rows}):
        mine = sorted((row for row in rows if row["replicas"] == r), key=lambda row: row["actors"])
        xs = [row["actors"] for row in mine]
        left.plot(xs, [row["fresh_steps_per_s"] for row in mine], "o-", label=f"{r} learner replica(s)")
        right.plot(xs, [100 * row["learner_share"] for row in mine], "o-", label=f"{r} learner replica(s)")
    for ax, label in ((left, "fresh samples / s"), (right, "learner share of wall time, %")):
        ax.set_xscale("log", base=2)
        ax.set_xlabel("rollout actors (one per simulated node)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend()
    right.set_ylim(0, 100)
    fig.suptitle(f"{meta['preset']}: {meta['cpus']} cores, {meta['iterations']} x {meta['steps_per_iteration']} steps per run")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


PROG = "morphmimic bench scaling"


@validated
@dataclass
class ScalingBenchOptions:
    preset: str = "reach"
    """Training preset to run."""
    actors: CommaInts = (1, 2, 4, 8)
    """Rollout actor counts."""
    replicas: CommaInts = (1, 2)
    """Learner replica counts."""
    envs_per_actor: int = 8
    """Environments per rollout actor."""
    iterations: int = 8
    """PPO iterations per run: the fixed step budget."""
    warmup: int = 3
    """Iterations excluded from the timing."""
    learner_threads: int = 1
    """Torch threads of each learner process."""
    address: str = ""
    """A running Ray cluster to measure instead of the local test cluster."""
    out: str = ""
    """Directory for scaling.json, scaling.md and scaling.png."""

    LIMITS: ClassVar[dict[str, Limit]] = {"actors": at_least(1), "replicas": at_least(1), "envs_per_actor": at_least(1), "iterations": at_least(1), "warmup": at_least(0), "learner_threads": at_least(1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_presets("--preset", [self.preset])
        if self.iterations <= self.warmup + 1:
            raise ValueError(f"--iterations {self.iterations} must exceed --warmup {self.warmup} by at least 2")
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(ScalingBenchOptions, argv, prog=PROG, description=__doc__)
    base = PRESETS[args.preset][1]
    for r in args.replicas:
        if base.ppo.minibatch % r:
            refuse(PROG, f"--replicas {r}: the preset's minibatch {base.ppo.minibatch} does not divide among them")
    cluster = None
    address = args.address
    if not address:
        cluster = start(rollout_per_worker=1, cpus_per_worker=1, learner_slots=max(args.replicas) - 1,
                        workers=max(args.actors))
        address = cluster.address
    print(f"task {base.task.name}, policy {base.policy.hidden}, {base.steps_per_iteration} steps/iteration, "
          f"cluster {address} ({'local test cluster, ' + str(max(args.actors)) + ' workers' if cluster else 'given'})", flush=True)
    try:
        rows = measure(base, address, args.actors, args.replicas, args.envs_per_actor, args.iterations, args.warmup,
                       args.learner_threads)
    finally:
        if cluster is not None:
            cluster.shutdown()
    if args.out:
        meta = {"preset": args.preset, "task": base.task.name, "hidden": list(base.policy.hidden),
                "steps_per_iteration": base.steps_per_iteration, "iterations": args.iterations, "warmup": args.warmup,
                "envs_per_actor": args.envs_per_actor, "learner_threads": args.learner_threads, "cpus": os.cpu_count(),
                "command": "morphmimic bench scaling " + " ".join(argv)}
        write(Path(args.out), meta, rows)
        print(f"wrote {args.out}/scaling.json, scaling.md, scaling.png")
    return 0
