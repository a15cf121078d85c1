"""`morphmimic bench replicas`: one PPO update in one process against the same update shared by
data-parallel replicas (`--learner.replicas`), same batch, same starting networks.

For each width: the preset's PPO settings (epochs, minibatch, transitions per update; the KL
stop off, so every minibatch step trains both networks) on one random batch of the preset's
observation and action sizes (`learner.bench.learner_update.random_batch`). First one process
runs `--updates` timed updates after one untimed; then `--replicas` processes in a gloo group on
127.0.0.1 (`learner.data_parallel`) run the same updates from the same state. Reported: seconds
per update of each, their ratio (the speed-up), and the largest parameter difference between
the single process and rank 0 afterwards (float sums in another order only).

Every process runs torch on one thread. The replicas compete for this machine's cores and
memory bus with anything else running: the ratio is what this machine gives, not what
separate nodes would.
"""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
import tempfile
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from common.config_limits import Limit, at_least, check_limits, validated
from common.policy import GaussianPolicy, PolicyConfig, ValueNet
from common.tasks.registry import make_env
from learner import data_parallel
from learner.bench.learner_update import random_batch
from learner.cli_options import CommaInts, parse_options, refuse
from learner.ppo import PPO, Batch
from learner.presets import PRESETS, check_presets


def build(preset: str, width: int) -> tuple[PPO, Batch]:
    """The preset's PPO (KL stop off) on 3 x `width` networks, and one random batch of its size."""
    cfg = PRESETS[preset][1]
    env = make_env(cfg.task, seed=0)
    obs_dim, act_dim = env.obs_dim, env.act_dim
    del env
    torch.manual_seed(0)
    pcfg = PolicyConfig(hidden=(width,) * 3)
    ppo = PPO(GaussianPolicy(obs_dim, act_dim, pcfg), ValueNet(obs_dim, pcfg), dataclasses.replace(cfg.ppo, kl_stop=0.0))
    return ppo, random_batch(ppo.policy, cfg.steps_per_iteration, cfg.actors.unroll_length, seed=1)


def flat(ppo: PPO) -> np.ndarray:
    return torch.cat([p.detach().reshape(-1).double() for p in (*ppo.policy.parameters(), *ppo.value.parameters())]).numpy()


def timed_updates(ppo: PPO, batch: Batch, updates: int, sync: data_parallel.GradientSync | None) -> float:
    """Seconds per update, after one untimed update."""
    gen = torch.Generator().manual_seed(0)
    ppo.update(batch, gen, sync)
    t0 = time.perf_counter()
    for _ in range(updates):
        ppo.update(batch, gen, sync)
    return (time.perf_counter() - t0) / updates


def _replica(rank: int, world: int, init_method: str, preset: str, width: int, updates: int, out) -> None:
    torch.set_num_threads(1)
    ppo, batch = build(preset, width)
    data_parallel.join(init_method, rank, world, torch.device("cpu"), timeout_s=600)
    try:
        seconds = timed_updates(ppo, batch, updates, data_parallel.GradientSync(rank, world))
        out.put((rank, seconds, flat(ppo) if rank == 0 else None))
    finally:
        data_parallel.leave()


def replicated(preset: str, width: int, updates: int, world: int) -> tuple[float, np.ndarray]:
    """(seconds per update of rank 0, rank 0's parameters) with `world` replicas."""
    ctx = mp.get_context("spawn")
    out = ctx.Queue()
    init_method = data_parallel.rendezvous("127.0.0.1", tempfile.gettempdir())
    procs = [ctx.Process(target=_replica, args=(r, world, init_method, preset, width, updates, out)) for r in range(world)]
    for p in procs:
        p.start()
    try:
        results = {rank: (s, params) for rank, s, params in (out.get(timeout=1800) for _ in range(world))}
    finally:
        for p in procs:
            p.join(timeout=60)
            if p.is_alive():
                p.kill()
    return results[0]


def measure(preset: str, width: int, updates: int, world: int) -> dict:
    ppo, batch = build(preset, width)
    single = timed_updates(ppo, batch, updates, None)
    shared, params = replicated(preset, width, updates, world)
    return {"preset": preset, "width": width, "replicas": world, "updates": updates, "single_s": single,
            "replicated_s": shared, "speedup": single / shared, "max_param_diff": float(np.abs(flat(ppo) - params).max())}


PROG = "morphmimic bench replicas"


@validated
@dataclass
class ReplicasBenchOptions:
    preset: str = "executor"
    """Preset whose task and PPO settings are used."""
    widths: CommaInts = (256, 1024)
    """Hidden widths of the 3-layer nets."""
    replicas: int = 2
    """Data-parallel processes (2 or more: one process is the other arm)."""
    updates: int = 2
    """Timed updates of each."""

    LIMITS: ClassVar[dict[str, Limit]] = {"widths": at_least(1), "replicas": at_least(2), "updates": at_least(1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_presets("--preset", [self.preset])
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(ReplicasBenchOptions, argv, prog=PROG, description=__doc__)
    if PRESETS[args.preset][1].ppo.minibatch % args.replicas:
        refuse(PROG, f"--replicas {args.replicas}: the preset's minibatch {PRESETS[args.preset][1].ppo.minibatch} does not divide among them")
    torch.set_num_threads(1)
    print(f"{args.preset}: one process vs {args.replicas} replicas (gloo, 127.0.0.1), one torch thread each, "
          f"{args.updates} timed updates", flush=True)
    for width in args.widths:
        m = measure(args.preset, width, args.updates, args.replicas)
        print(f"  3 x {width:5d}: one process {m['single_s']:7.2f} s per update, {args.replicas} replicas {m['replicated_s']:7.2f} s; "
              f"speed-up {m['speedup']:.2f}; largest parameter difference {m['max_param_diff']:.1e}", flush=True)
    return 0
