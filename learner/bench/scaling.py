"""`morphmimic bench scaling`: fresh samples per second against rollout actors and learner replicas.

The tool a cluster user runs to size a deployment. It starts the local test cluster of
`deploy/local_cluster.py` with as many worker nodes as the largest actor count (one rollout actor
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

import argparse
import dataclasses
import json
import os
import tempfile
from pathlib import Path

from learner.bench.throughput import end_to_end
from learner.config import LearnerConfig, RunConfig
from learner.evaluation.cli_args import positive_int, positive_ints
from learner.presets import PRESETS


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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="morphmimic bench scaling", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="reach", choices=sorted(PRESETS), help="training preset to run")
    parser.add_argument("--actors", type=positive_ints, default=[1, 2, 4, 8], help="rollout actor counts (default 1,2,4,8)")
    parser.add_argument("--replicas", type=positive_ints, default=[1, 2], help="learner replica counts (default 1,2)")
    parser.add_argument("--envs-per-actor", type=positive_int, default=8)
    parser.add_argument("--iterations", type=positive_int, default=8, help="PPO iterations per run: the fixed step budget")
    parser.add_argument("--warmup", type=int, default=3, help="iterations excluded from the timing")
    parser.add_argument("--learner-threads", type=positive_int, default=1, help="torch threads of each learner process")
    parser.add_argument("--address", default="", help="a running Ray cluster to measure instead of the local test cluster")
    parser.add_argument("--out", default="", help="directory for scaling.json, scaling.md and scaling.png")
    args = parser.parse_args(argv)
    if args.warmup < 0:
        parser.error(f"--warmup {args.warmup}: give 0 or more iterations")
    if args.iterations <= args.warmup + 1:
        parser.error(f"--iterations {args.iterations} must exceed --warmup {args.warmup} by at least 2")
    base = PRESETS[args.preset][1]
    for r in args.replicas:
        if base.ppo.minibatch % r:
            parser.error(f"--replicas {r}: the preset's minibatch {base.ppo.minibatch} does not divide among them")
    cluster = None
    address = args.address
    if not address:
        from learner.cluster import start_test_cluster as start

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
