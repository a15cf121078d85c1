"""`morphmimic bench capacity`: the per-sample costs a cluster's capacity model needs, by network width.

How many rollout actors does one learner process keep up with at a given network width, and would
batching the actors' policy inference in one central server pay? Both follow from a handful of
per-sample costs, measured here in one run per preset (its task, environments per actor, unroll
shape and PPO settings) for each hidden width `w` of a 3 x w policy and value net. Torch runs
single-threaded throughout, as the learner and the actors do next to each other.

Width-independent, once per preset:
- simulation: one actor's `envs_per_actor` environments stepped with zero actions, one unroll
  (`unroll_length` control steps of all of them) per timed block; an episode that ends is reset
  on new parameters drawn uniformly from the task's space, and the resets count in the time (a
  young policy's episodes are as short as these: the episodes ended per 1000 steps are printed);
- transport: the bytes of one encoded `UnrollMsg` of the preset's shape per environment step,
  and the learner's decode of it (`wire.decode` with the shape pinned, as `learner.transport`
  calls it) per step. The message's header lists no ended episodes (a real one adds a few bytes
  per episode);
- an inference round trip: one actor's observations `[envs_per_actor, obs_dim]` float32 over a
  plain (not CURVE) ZeroMQ REQ/REP pair on tcp://127.0.0.1 to a server process that replies
  with a zero `[envs_per_actor, act_dim]` float32 array: the latency a central (SEED RL style)
  inference server adds to every control step of an actor, before it computes anything.

Per width:
- inference: `GaussianPolicy.act` (numpy in and out, as actors call it) per sample, at the
  actor's batch (`envs_per_actor`) and at 64, 256 and 1024 (what a central server would batch);
- the PPO update: `PPO.update` on a random batch of the preset's size (`learner_update.random_batch`),
  each timed update starting from the same fresh networks, after one untimed warm-up update on a
  sixteenth of the batch (it warms the kernels and the allocator; a whole one costs 20 s at 1024).
  The preset's KL stop is off: on random data, fresh networks and a fresh Adam (whose first steps
  are full-size) it stopped the policy after the first minibatch step at widths from 256 up, and
  the value-only steps that follow cost about half a training step. Reported per collected sample
  (update seconds / steps per iteration, so the preset's epochs are in it) and per minibatch step.
  Wide nets take fewer timed updates: once a width's timed updates passed `--update-budget-s`, no
  more are run (the table's "upd" column says how many ran);
- all-reduce: two processes in a gloo group on 127.0.0.1 all-reduce a float32 tensor as large
  as the policy's and value net's trained parameters (plus the loss record the sync adds): the
  median of 50 calls, what `--learner.replicas 2` adds to every minibatch step
  (`learner.data_parallel`), next to the minibatch step's own compute;
- actors one learner serves = (simulation + inference at the actor's batch) / update, per
  sample: the simulating cores one learner process keeps up with.

How to read it: per-sample costs add up. An actor core spends sim + inference per step; a
learner core spends update per step; a central inference server would replace the actors'
inference (at their batch) by the server's (at its batch) plus a round trip per control step,
which the actor waits through unless it steps other environments meanwhile. Absolute figures
move with the machine's load (the header prints the load average): read the ratios.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import multiprocessing as mp
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from queue import Empty
from typing import ClassVar

import numpy as np
import torch
import torch.distributed as dist
import zmq

from common import wire
from common.config_limits import Limit, above, at_least, check_limits, validated
from common.policy import GaussianPolicy, ValueNet
from common.tasks.registry import make_env
from learner import data_parallel
from learner.bench.learner_update import random_batch
from learner.cli_options import CommaInts, CommaStrs, parse_options
from learner.config import RunConfig
from learner.ppo import PPO, Batch
from learner.presets import PRESETS, check_presets


SERVER_BATCHES = (64, 256, 1024)
"""Inference batch sizes a central server would run, besides each actor's own."""
ALLREDUCE_CALLS = 50
ROUND_TRIPS = 1000
BLOCK_S = 0.05
"""Target duration of one timed block of a fast operation (inference, decode): repeated calls."""
SYNC_RECORD = 7
"""Floats `GradientSync.average_` all-reduces besides the gradients: 6 loss metrics and a finite flag."""


def median_seconds(fn: Callable[[], object], repeats: int) -> float:
    """Median seconds per call of `fn` over `repeats` blocks of about `BLOCK_S` each (one call
    first, untimed, warms up and sizes the blocks)."""
    start = time.perf_counter()
    fn()
    calls = max(1, round(BLOCK_S / max(time.perf_counter() - start, 1e-9)))
    blocks = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        blocks.append((time.perf_counter() - start) / calls)
    return statistics.median(blocks)


def simulation_cost(cfg: RunConfig, repeats: int, seed: int = 0) -> dict[str, float]:
    """Microseconds per environment step of one actor's environments under zero actions, resets included."""
    T, N = cfg.actors.unroll_length, cfg.actors.envs_per_actor
    rng = np.random.default_rng(seed)
    envs = [make_env(cfg.task, seed=seed * 10_007 + i) for i in range(N)]
    for env in envs:
        env.reset(int(rng.integers(2**31)), env.space.uniform(rng, 1)[0])
    zero = np.zeros(envs[0].act_dim, np.float32)
    episodes = 0

    def unroll() -> None:
        nonlocal episodes
        for _ in range(T):
            for env in envs:
                _, _, terminated, truncated, _ = env.step(zero)
                if terminated or truncated:
                    episodes += 1
                    env.reset(int(rng.integers(2**31)), env.space.uniform(rng, 1)[0])

    unroll()  # warm-up: a process's first episodes fill its caches
    episodes, blocks = 0, []
    for _ in range(repeats):
        start = time.perf_counter()
        unroll()
        blocks.append(time.perf_counter() - start)
    return {"us_per_step": 1e6 * statistics.median(blocks) / (T * N),
            "episodes_per_1000_steps": 1000 * episodes / (repeats * T * N)}


def unroll_message(T: int, N: int, obs_dim: int, act_dim: int, n_params: int, seed: int = 0) -> wire.UnrollMsg:
    """An `UnrollMsg` of shape `[T, N, ...]` filled with random values (the first of an actor's, no ended episodes)."""
    rng = np.random.default_rng(seed)

    def f32(*shape: int) -> np.ndarray:
        return rng.standard_normal(shape, dtype=np.float32)

    return wire.UnrollMsg(actor_id=0, seq=0, policy_version=0, obs=f32(T, N, obs_dim), next_obs=f32(T, N, obs_dim),
                          actions=f32(T, N, act_dim), logp=f32(T, N), rewards=f32(T, N),
                          terminated=rng.random((T, N)) < 0.03, truncated=np.zeros((T, N), bool),
                          params=f32(T, N, n_params))


def transport_cost(T: int, N: int, obs_dim: int, act_dim: int, n_params: int, repeats: int) -> dict[str, float]:
    """Bytes on the wire and the learner's decode time, per environment step of one unroll."""
    frames = [bytes(f) for f in wire.encode(unroll_message(T, N, obs_dim, act_dim, n_params))]
    dims = {"T": T, "N": N, "obs_dim": obs_dim, "act_dim": act_dim, "n_params": n_params}
    size = sum(len(f) for f in frames)

    def decode() -> wire.UnrollMsg:
        return wire.decode(frames, expect=(wire.UnrollMsg, wire.HeartbeatMsg), dims=dims)

    return {"message_bytes": size, "bytes_per_step": size / (T * N),
            "decode_us_per_step": 1e6 * median_seconds(decode, repeats) / (T * N)}


def _answer(queue: mp.Queue, procs: list[mp.Process], timeout_s: float = 600.0) -> object:
    """The first item a child process puts on `queue`; RuntimeError as soon as one of `procs` failed
    or all exited without answering (rather than waiting out the timeout)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            return queue.get(timeout=1.0)
        except Empty:
            codes = [p.exitcode for p in procs]
            if any(c not in (None, 0) for c in codes) or all(c is not None for c in codes) and queue.empty():
                raise RuntimeError(f"a measuring process ended without answering: exit codes {codes}") from None
    raise TimeoutError(f"no answer from the measuring processes within {timeout_s:.0f} s")


def _echo_server(reply_bytes: int, ports: mp.Queue) -> None:
    """A REP socket that answers every request with `reply_bytes` zero bytes; b"stop" ends it."""
    ctx = zmq.Context()
    sock = ctx.socket(zmq.REP)
    ports.put(sock.bind_to_random_port("tcp://127.0.0.1"))
    reply = bytes(reply_bytes)
    while True:
        request = sock.recv()
        sock.send(reply)
        if request == b"stop":
            break
    sock.close(linger=1000)
    ctx.term()


def round_trip_us(N: int, obs_dim: int, act_dim: int, trips: int = ROUND_TRIPS) -> float:
    """Median microseconds for `[N, obs_dim]` float32 observations to a server process and `[N, act_dim]` back."""
    spawn = mp.get_context("spawn")
    ports = spawn.Queue()
    server = spawn.Process(target=_echo_server, args=(N * act_dim * 4, ports), daemon=True)
    server.start()
    ctx = zmq.Context()
    sock = ctx.socket(zmq.REQ)
    try:
        sock.connect(f"tcp://127.0.0.1:{_answer(ports, [server])}")
        obs = np.random.default_rng(0).standard_normal((N, obs_dim), dtype=np.float32)
        times = []
        for i in range(trips + trips // 10):  # the first tenth untimed: connection set-up, first wake-ups
            start = time.perf_counter()
            sock.send(obs, copy=False)
            np.frombuffer(sock.recv(), np.float32).reshape(N, act_dim)
            if i >= trips // 10:
                times.append(time.perf_counter() - start)
        sock.send(b"stop")
        sock.recv()
    finally:
        sock.close(linger=0)
        ctx.term()
        server.join(timeout=30)
        if server.is_alive():
            server.kill()
    return 1e6 * statistics.median(times)


def inference_us(policy: GaussianPolicy, batch: int, repeats: int) -> float:
    """Microseconds per sample of `policy.act` on a `[batch, obs_dim]` numpy array."""
    obs = np.random.default_rng(batch).standard_normal((batch, policy.obs_dim), dtype=np.float32)
    return 1e6 * median_seconds(lambda: policy.act(obs), repeats) / batch


def _columns(batch: Batch, b: int) -> Batch:
    """The first `b` environment streams of a time-major batch."""
    return Batch(*(getattr(batch, f.name)[:, :b] for f in dataclasses.fields(batch)))


def update_cost(policy: GaussianPolicy, value: ValueNet, cfg: RunConfig, repeats: int, budget_s: float,
                seed: int = 0) -> dict[str, float]:
    """`PPO.update` on a random batch of the preset's size, its KL stop off (every minibatch step trains
    both networks): microseconds per collected sample and per minibatch step (medians), over up to
    `repeats` updates from the same start, fewer once they took `budget_s`."""
    T = cfg.actors.unroll_length
    batch = random_batch(policy, cfg.steps_per_iteration, T, seed)
    start = PPO(policy, value, dataclasses.replace(cfg.ppo, kl_stop=0.0))
    B = batch.rewards.shape[1]
    copy.deepcopy(start).update(_columns(batch, min(B, max(B // 16, math.ceil(cfg.ppo.minibatch / T)))),
                                torch.Generator().manual_seed(seed))
    seconds: list[float] = []
    steps: list[float] = []
    while len(seconds) < repeats and sum(seconds) < budget_s:
        ppo = copy.deepcopy(start)
        generator = torch.Generator().manual_seed(seed + len(seconds))
        t0 = time.perf_counter()
        metrics = ppo.update(batch, generator)
        seconds.append(time.perf_counter() - t0)
        steps.append(metrics["minibatch_steps"])
    return {"us_per_sample": 1e6 * statistics.median(seconds) / cfg.steps_per_iteration,
            "minibatch_step_us": 1e6 * statistics.median(s / n for s, n in zip(seconds, steps)),
            "minibatch_steps": statistics.median(steps), "updates_timed": len(seconds)}


def _allreduce_rank(init_method: str, rank: int, sizes: list[int], calls: int, out: mp.Queue) -> None:
    torch.set_num_threads(1)
    data_parallel.join(init_method, rank, 2, torch.device("cpu"), timeout_s=120)
    try:
        medians = []
        for n in sizes:
            flat = torch.ones(n)
            times = []
            for i in range(calls + 5):  # the first 5 untimed: gloo sets up its buffers per size
                start = time.perf_counter()
                dist.all_reduce(flat)
                if i >= 5:
                    times.append(time.perf_counter() - start)
                flat.div_(2)  # as the sync averages (and keeps the values finite)
            medians.append(statistics.median(times))
        if rank == 0:
            out.put(medians)
    finally:
        data_parallel.leave()


def allreduce_us(sizes: list[int], calls: int = ALLREDUCE_CALLS) -> list[float]:
    """Median microseconds per all-reduce of a float32 tensor of each size between two processes on 127.0.0.1."""
    spawn = mp.get_context("spawn")
    out = spawn.Queue()
    init_method = data_parallel.rendezvous("127.0.0.1", tempfile.gettempdir())
    procs = [spawn.Process(target=_allreduce_rank, args=(init_method, r, sizes, calls, out)) for r in range(2)]
    for p in procs:
        p.start()
    try:
        medians = _answer(out, procs)
    finally:
        for p in procs:
            p.join(timeout=60)
            if p.is_alive():
                p.kill()
    return [1e6 * m for m in medians]


def measure(preset: str, widths: list[int], repeats: int, update_budget_s: float) -> dict:
    """Every figure of one preset (printed as it goes: the wide updates take a while)."""
    cfg = PRESETS[preset][1]
    T, N = cfg.actors.unroll_length, cfg.actors.envs_per_actor
    env = make_env(cfg.task, seed=0)
    obs_dim, act_dim, n_params = env.obs_dim, env.act_dim, env.space.dim
    del env
    print(f"{preset}: task {cfg.task.name}, obs {obs_dim}, act {act_dim}, {N} environments per actor, unroll {T}, "
          f"{cfg.steps_per_iteration} steps per update ({cfg.ppo.epochs} epochs x {cfg.ppo.minibatch})", flush=True)
    result = {
        "preset": preset, "task": cfg.task.name, "obs_dim": obs_dim, "act_dim": act_dim, "n_params": n_params,
        "envs_per_actor": N, "unroll_length": T, "steps_per_iteration": cfg.steps_per_iteration,
        "epochs": cfg.ppo.epochs, "minibatch": cfg.ppo.minibatch,
        "simulation": simulation_cost(cfg, repeats),
        "transport": transport_cost(T, N, obs_dim, act_dim, n_params, repeats),
        "round_trip_us": round_trip_us(N, obs_dim, act_dim),
    }
    batches = sorted({N, *SERVER_BATCHES})
    rows, sizes = [], []
    for w in widths:
        torch.manual_seed(0)
        pcfg = dataclasses.replace(cfg.policy, hidden=(w, w, w))
        policy, value = GaussianPolicy(obs_dim, act_dim, pcfg), ValueNet(obs_dim, pcfg)
        sizes.append(sum(p.numel() for p in (*policy.parameters(), *value.parameters()) if p.requires_grad))
        inference = {str(b): inference_us(policy, b, repeats) for b in batches}
        update = update_cost(policy, value, cfg, repeats, update_budget_s)
        rows.append({"width": w, "trained_parameters": sizes[-1], "inference_us_per_sample": inference,
                     "update": update})
        print(f"  width {w}: update {update['us_per_sample']:.0f} us per sample ({update['updates_timed']} timed)",
              flush=True)
    for row, us in zip(rows, allreduce_us([n + SYNC_RECORD for n in sizes])):
        row["allreduce_us"] = us
        actor_us = result["simulation"]["us_per_step"] + row["inference_us_per_sample"][str(N)]
        row["actors_one_learner_serves"] = actor_us / row["update"]["us_per_sample"]
    result["widths"] = rows
    return result


LEGEND = ("us: microseconds per sample unless named; infer@B: `policy.act` at batch B; upd: timed updates; "
          "mb step: one minibatch step's compute; all-reduce: per minibatch step with 2 replicas; actors served: "
          "(simulation + infer at the actor's batch) / update, per sample")


def _table(m: dict) -> list[list[str]]:
    """Header and one row per width: the per-width figures as text."""
    batches = list(m["widths"][0]["inference_us_per_sample"])
    head = ["width", "parameters", *(f"infer@{b}" for b in batches), "update", "upd", "mb step us", "all-reduce us",
            "actors served"]
    rows = [[str(r["width"]), f"{r['trained_parameters']:,}",
             *(f"{r['inference_us_per_sample'][b]:.1f}" for b in batches), f"{r['update']['us_per_sample']:.0f}",
             str(r["update"]["updates_timed"]), f"{r['update']['minibatch_step_us']:.0f}", f"{r['allreduce_us']:.0f}",
             f"{r['actors_one_learner_serves']:.2f}"] for r in m["widths"]]
    return [head, *rows]


def _fixed(m: dict) -> list[str]:
    """The width-independent figures, one line each."""
    sim, tr, n = m["simulation"], m["transport"], m["envs_per_actor"]
    return [(f"simulation {sim['us_per_step']:.0f} us per environment step (zero actions, resets included: "
             f"{sim['episodes_per_1000_steps']:.1f} episodes ended per 1000 steps)"),
            (f"transport {tr['bytes_per_step']:.0f} bytes per step (one unroll {tr['message_bytes'] / 1e3:.0f} kB), "
             f"decode {tr['decode_us_per_step']:.2f} us per step"),
            (f"inference round trip {m['round_trip_us']:.0f} us ({n} x {m['obs_dim']} float32 out, "
             f"{n} x {m['act_dim']} back, plain REQ/REP on 127.0.0.1)")]


def print_report(m: dict) -> None:
    for line in _fixed(m):
        print(f"  {line}")
    table = _table(m)
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    for row in table:
        print("  " + "  ".join(cell.rjust(w) for cell, w in zip(row, widths)))
    print(f"  ({LEGEND})", flush=True)


def write(out: Path, meta: dict, results: list[dict]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "capacity.json").write_text(json.dumps({**meta, "presets": results}, indent=2) + "\n")
    lines = ["# Capacity: per-sample costs by network width", "", f"`{meta['command']}`", "",
             (f"{meta['cpus']} cores, torch {meta['torch']} on 1 thread, load average {meta['load_average'][0]:.1f} at "
              f"the start. {LEGEND}."), ""]
    for m in results:
        table = _table(m)
        lines += [(f"## {m['preset']} (obs {m['obs_dim']}, act {m['act_dim']}, {m['envs_per_actor']} environments per "
                   f"actor, {m['steps_per_iteration']} steps per update, {m['epochs']} epochs x {m['minibatch']})"), "",
                  *(f"- {line}" for line in _fixed(m)), "",
                  "| " + " | ".join(table[0]) + " |", "|" + "---|" * len(table[0]),
                  *("| " + " | ".join(row) + " |" for row in table[1:]), ""]
    (out / "capacity.md").write_text("\n".join(lines))


PROG = "morphmimic bench capacity"


@validated
@dataclass
class CapacityBenchOptions:
    presets: CommaStrs = ("executor", "lower_biped")
    """Comma-separated training presets."""
    widths: CommaInts = (128, 256, 512, 1024)
    """Hidden widths of the 3-layer nets."""
    repeats: int = 5
    """Timed blocks (updates: at most) per measurement."""
    update_budget_s: float = 8.0
    """No further timed update of a width once its timed updates took this long."""
    out: str = ""
    """Directory for capacity.json and capacity.md."""

    LIMITS: ClassVar[dict[str, Limit]] = {"widths": at_least(1), "repeats": at_least(1), "update_budget_s": above(0)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_presets("--presets", self.presets)
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(CapacityBenchOptions, argv, prog=PROG, description=__doc__)
    presets = args.presets
    torch.set_num_threads(1)
    load = os.getloadavg()
    print(f"{os.cpu_count()} cores, torch {torch.__version__} on 1 thread, load average {load[0]:.1f} "
          "(absolute figures grow with it)", flush=True)
    results = []
    for preset in presets:
        results.append(measure(preset, args.widths, args.repeats, args.update_budget_s))
        print_report(results[-1])
    if args.out:
        meta = {"command": " ".join(["morphmimic bench capacity", *argv]), "torch": torch.__version__,
                "cpus": os.cpu_count(), "load_average": list(load), "repeats": args.repeats,
                "update_budget_s": args.update_budget_s, "allreduce_calls": ALLREDUCE_CALLS, "round_trips": ROUND_TRIPS}
        write(Path(args.out), meta, results)
        print(f"wrote {args.out}/capacity.json and capacity.md")
    return 0
