"""`train(cfg)`: the whole run. Joins or starts Ray (or none in serial mode), starts the sampler
service and the rollout actors, runs PPO iterations on the unrolls that stream in, publishes
weights, logs, checkpoints, and on the step budget, Ctrl-C or SIGTERM stops everything cleanly.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import signal
import threading
import time
from pathlib import Path

import torch

from common.tasks.registry import task_clips, task_space
from learner import checkpoint, cluster
from learner.actor_pool import RayActorPool, SerialActorPool
from learner.config import RunConfig
from learner.learner import Learner
from learner.run_log import RunLog
from learner.sampler_handle import SamplerHandle
from learner.transport import LearnerTransport

log = logging.getLogger(__name__)

WAIT_WARN_S = 15.0
"""Say so on the console when no usable unroll arrived for this long."""


class StopFlag:
    """Set by SIGINT/SIGTERM; a second signal forces an immediate KeyboardInterrupt."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.previous: dict[int, object] = {}

    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            self.previous[sig] = signal.signal(sig, self._handle)

    def _handle(self, signum, frame) -> None:
        if self.event.is_set():
            raise KeyboardInterrupt
        print(f"\n[morphmimic] {signal.Signals(signum).name}: checkpointing and stopping (again to force)", flush=True)
        self.event.set()

    def restore(self) -> None:
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)

    def __bool__(self) -> bool:
        return self.event.is_set()


def prepare_run_dir(cfg: RunConfig) -> tuple[Path, tuple[Path, dict] | None]:
    """Create the run directory; find the checkpoint to resume from per `cfg.resume`."""
    run_dir = Path(cfg.runs_dir) / cfg.name
    ckpt_dir = run_dir / "ckpt"
    resume_from = None
    if cfg.resume == "auto":
        resume_from = checkpoint.load_latest(ckpt_dir)
    elif cfg.resume == "never":
        if checkpoint.list_checkpoints(ckpt_dir):
            raise SystemExit(
                f"run {run_dir} already has checkpoints; use --resume auto to continue it, or another --name"
            )
    else:
        path = Path(cfg.resume)
        resume_from = (path, checkpoint.load(path))
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(cfg.to_json() + "\n")
    return run_dir, resume_from


class Collector:
    """Gathers each iteration's batch: exactly `steps_per_iteration` transitions (rounded up to
    whole unrolls), oldest first. Unrolls that arrive beyond that wait for the next iteration,
    where they are used if still within the allowed policy lag, else dropped and counted."""

    def __init__(self, transport: LearnerTransport, pool, cfg: RunConfig, stop: StopFlag, serial: bool, out: RunLog):
        self.transport, self.pool, self.cfg, self.stop, self.serial, self.out = transport, pool, cfg, stop, serial, out
        self.pending: list = []

    def _fresh(self, policy_version: int) -> None:
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
        while steps < self.cfg.steps_per_iteration:
            u = self.pending.pop(0)
            batch.append(u)
            steps += u.rewards.size
        return batch


def train(cfg: RunConfig, on_iteration=None) -> int:
    """Run training to the step budget; `on_iteration(metrics)` is called after each iteration
    (benchmarks use it). Returns the process exit code."""
    run_dir, resume_from = prepare_run_dir(cfg)
    out = RunLog(run_dir, quiet=cfg.quiet)
    stop = StopFlag()
    serial = cfg.mode == "serial"
    ctx = None if serial else cluster.connect(cfg.mode, cfg.ray_address, cfg.actors.num_actors, cfg.actors.num_cpus)
    stop.install()  # after ray.init, which installs handlers of its own
    torch.set_num_threads(cfg.resolved_learner_threads)
    learner = Learner(cfg)
    if resume_from is not None:
        path, state = resume_from
        learner.load_state_dict(state)
        out.line(f"[morphmimic] resumed {path} at iteration {learner.iteration}, {learner.env_steps:,d} env steps")
    host = cluster.bind_host(ctx, cfg.bind_host)
    transport = LearnerTransport(host, learner.obs_dim, learner.act_dim, learner.space.dim, cfg.port_base)
    sampler = pool = None
    last_saved = learner.iteration if resume_from is not None else -1
    try:
        sampler_cfg = dataclasses.replace(
            cfg.sampler, host=host if host == "127.0.0.1" or ctx is None else "auto", seed=cfg.sampler.seed + cfg.seed, port=cfg.port_base + 3 if cfg.port_base else cfg.sampler.port
        )
        sampler = SamplerHandle.start(sampler_cfg, task_space(cfg.task), task_clips(cfg.task), ctx)
        if resume_from is not None and resume_from[1].get("sampler"):
            sampler.client.set_state(checkpoint.from_checkpointable(resume_from[1]["sampler"]))
        endpoints = {**transport.endpoints, "sampler": sampler.endpoint}
        out.line(f"[morphmimic] run {run_dir} | mode {ctx.kind if ctx else 'serial'} | endpoints {endpoints}")
        transport.publish(learner.weights_msg())
        pool = SerialActorPool(cfg, endpoints) if serial else RayActorPool(cfg, endpoints, ctx)
        collector = Collector(transport, pool, cfg, stop, serial, out)
        start_steps, start_time = learner.env_steps, time.monotonic()
        while learner.env_steps < cfg.total_env_steps and not stop:
            if cfg.max_iterations and learner.iteration >= cfg.max_iterations:
                break
            t0 = time.monotonic()
            unrolls = collector.next_batch(learner.policy_version)
            if unrolls is None:
                break
            t1 = time.monotonic()
            metrics = learner.update(unrolls)
            transport.publish(learner.weights_msg())
            t2 = time.monotonic()
            params, values = learner.value_pairs(unrolls, cfg.value_pairs_per_iteration)
            metrics.update(sampler.report_and_tick(params, values, learner.iteration))
            if cfg.vm_plot_every and learner.iteration % cfg.vm_plot_every == 0:
                sampler.plot(run_dir / "sampler_vm.png")
            metrics.update(_wire_metrics(transport, learner, pool))
            metrics["stats/learner_share"] = (t2 - t1) / max(time.monotonic() - t0, 1e-9)
            rate = (learner.env_steps - start_steps) / max(time.monotonic() - start_time, 1e-9)
            metrics["charts/steps_per_s"] = rate
            eta = max(0, cfg.total_env_steps - learner.env_steps) / rate if rate > 0 else float("inf")
            metrics["stats/update_s"] = t2 - t1
            metrics["stats/env_steps"] = float(learner.env_steps)
            out.iteration(learner.iteration, learner.env_steps, cfg.total_env_steps, rate, eta, metrics)
            if on_iteration is not None:
                on_iteration(metrics)
            if learner.iteration % cfg.checkpoint_every == 0:
                _save(run_dir, learner, sampler, cfg)
                last_saved = learner.iteration
        if learner.iteration != last_saved:
            _save(run_dir, learner, sampler, cfg)
        if sampler is not None:
            sampler.plot(run_dir / "sampler_vm.png")
        reason = "stopped by signal" if stop else "step budget reached" if learner.env_steps >= cfg.total_env_steps else "iteration limit reached"
        out.line(f"[morphmimic] {reason}: iteration {learner.iteration}, {learner.env_steps:,d} env steps; outputs in {run_dir}")
        return 0
    finally:
        if pool is not None:
            (run_dir / "actors.json").write_text(json.dumps(pool.stats(), indent=2) + "\n")
            pool.stop()
        if sampler is not None:
            sampler.stop()
        transport.close()
        out.close()
        cluster.shutdown(ctx)
        stop.restore()


def _save(run_dir: Path, learner: Learner, sampler: SamplerHandle, cfg: RunConfig) -> None:
    state = learner.state_dict()
    sampler_state = sampler.state()
    if sampler_state is not None:
        state["sampler"] = checkpoint.to_checkpointable(sampler_state)
    checkpoint.save(run_dir / "ckpt", learner.iteration, state, cfg.keep_checkpoints)


def _wire_metrics(transport: LearnerTransport, learner: Learner, pool) -> dict[str, float]:
    c = transport.counters
    rejected = sum(v for k, v in c.items() if k.startswith("rejected/")) + sum(transport.snapshots.rejected.values())
    out = {
        "wire/unrolls_received": float(c["unrolls_received"]),
        "wire/steps_received": float(c["steps_received"]),
        "wire/stale_unrolls": float(c["stale_unrolls"]),
        "wire/seq_gap_unrolls": float(c["seq_gap_unrolls"]),
        "wire/rejected": float(rejected),
        "wire/bytes_received": float(transport.bytes_received),
        "wire/snapshots_served": float(c["snapshots_served"]),
        "stats/divergences": float(learner.counters["divergences"]),
        "stats/actors_alive": float(pool.alive()),
    }
    for k, v in c.items():
        if k.startswith("rejected/"):
            out[f"wire/{k}"] = float(v)
    return out

