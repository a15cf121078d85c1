"""`train(cfg)`: the whole run. Joins or starts Ray (or none in serial mode), starts the sampler
service and the rollout actors, runs PPO iterations on the unrolls that stream in, publishes
weights, logs, checkpoints, and on the step budget, Ctrl-C or SIGTERM stops everything cleanly.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NoReturn

import torch

from common.curve_keys import RunKeys
from common.tasks.registry import task_clip_durations, task_clips, task_space
from learner import checkpoint, cluster
from learner.actor_pool import RayActorPool, SerialActorPool
from learner.collector import Collector
from learner.config import RunConfig
from learner.health import HealthMonitor
from learner.learner import Learner
from learner.replicas import ReplicaGroup
from learner.run_log import RunLog
from learner.scalar_sinks import open_sink
from learner.sampler_handle import SamplerHandle
from learner.signals import StopFlag
from learner.transport import LearnerTransport
from learner.unroll_bounds import UnrollBounds

log = logging.getLogger(__name__)

def usage_error(message: str) -> NoReturn:
    """One line on stderr and exit code 2, as for any bad command-line value."""
    print(f"python -m learner.main: {message}", file=sys.stderr)
    raise SystemExit(2)


def find_resume(cfg: RunConfig) -> tuple[Path, tuple[Path, dict] | None]:
    """The run directory (not created yet) and the checkpoint to resume from per `cfg.resume`."""
    run_dir = Path(cfg.runs_dir) / cfg.name
    ckpt_dir = run_dir / "ckpt"
    resume_from = None
    if cfg.resume == "auto":
        resume_from = checkpoint.load_latest(ckpt_dir)
    elif cfg.resume == "never":
        if checkpoint.list_checkpoints(ckpt_dir):
            usage_error(f"run {run_dir} already has checkpoints; use --resume auto to continue it, or another --name")
    else:
        path = Path(cfg.resume)
        try:
            resume_from = (path, checkpoint.load(path))
        except checkpoint.CheckpointError as exc:
            usage_error(f"--resume {cfg.resume}: {exc}. Give a checkpoint directory, or auto, or never.")
    return run_dir, resume_from


def resumed_learner(cfg: RunConfig, resume_from: tuple[Path, dict] | None) -> Learner:
    """The learner, with the checkpoint's state if resuming; a checkpoint of another task or
    network is a usage error (exit 2) before anything is written."""
    try:
        learner = Learner(cfg)
    except ValueError as exc:  # a device this machine does not have
        usage_error(str(exc))
    if resume_from is not None:
        path, state = resume_from
        try:
            learner.load_state_dict(state)
        except (RuntimeError, KeyError, ValueError, TypeError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            usage_error(f"checkpoint {path} does not fit preset/task {cfg.task.name!r} with policy {cfg.policy.hidden} "
                        f"({type(exc).__name__}: {first}); give the same --preset and network it was trained with")
    return learner


@dataclass
class Run:
    """Everything a running training job holds. Fault-injection tests and the soak benchmark
    receive it in their `on_iteration` hook to reach actors, sockets and the sampler."""

    cfg: RunConfig
    run_dir: Path
    out: RunLog
    stop: StopFlag
    ctx: cluster.RayContext | None
    learner: Learner
    transport: LearnerTransport
    sampler: SamplerHandle | None = None
    pool: SerialActorPool | RayActorPool | None = None
    collector: Collector | None = None
    health: HealthMonitor | None = None
    last_saved: int = -1
    keys: RunKeys | None = None
    """This run's CURVE keys (`common.curve_keys`), made at start; None with `--no-curve`."""

    def save(self) -> None:
        state = self.learner.state_dict()
        state["transport"] = self.transport.state_dict()
        sampler_state = self.sampler.state()
        if sampler_state is not None:
            self.sampler.saved_state = sampler_state
        elif self.sampler.saved_state is not None:
            # NOTE: the sampler did not answer: the previous checkpoint's state is kept rather than
            # none, so a resume from this checkpoint does not restart the sampler from scratch.
            self.out.line(f"[morphmimic] sampler state unavailable at iteration {self.learner.iteration}; "
                          "this checkpoint keeps the previous one's")
            sampler_state = self.sampler.saved_state
        if sampler_state is not None:
            state["sampler"] = checkpoint.to_checkpointable(sampler_state)
        checkpoint.save(self.run_dir / "ckpt", self.learner.iteration, state, self.cfg.keep_checkpoints)
        self.last_saved = self.learner.iteration


def _start(cfg: RunConfig) -> Run:
    run_dir, resume_from = find_resume(cfg)
    torch.set_num_threads(cfg.resolved_learner_threads)
    learner = resumed_learner(cfg, resume_from)
    run_dir.mkdir(parents=True, exist_ok=True)  # NOTE: only once the configuration and checkpoint are known good
    (run_dir / "config.json").write_text(cfg.to_json() + "\n")
    out = RunLog(run_dir, quiet=cfg.quiet, sink=open_sink(cfg.logger, run_dir, cfg.name, cfg))
    if resume_from is not None:
        out.line(f"[morphmimic] resumed {resume_from[0]} at iteration {learner.iteration}, {learner.env_steps:,d} env steps")
    stop = StopFlag()
    ctx = None if cfg.mode == "serial" else cluster.connect(cfg.mode, cfg.ray_address, cfg.actors.num_actors, cfg.actors.num_cpus,
                                                             cfg.learner.replicas)
    stop.install()  # after ray.init, which installs handlers of its own
    host = cluster.bind_host(ctx, cfg.bind_host)
    if not cfg.actors.seq_ledger_dir and host == "127.0.0.1":
        cfg = dataclasses.replace(cfg, actors=dataclasses.replace(cfg.actors, seq_ledger_dir=str(run_dir / "ledger")))
    keys = RunKeys.generate(cfg.actors.num_actors) if cfg.curve else None  # NOTE: per run and per session, never written to disk
    transport = LearnerTransport(host, learner.obs_dim, learner.act_dim, learner.space.dim, cfg.port_base,
                                 unroll_length=cfg.actors.unroll_length, envs_per_actor=cfg.actors.envs_per_actor,
                                 num_actors=cfg.actors.num_actors, keys=keys, bounds=UnrollBounds.for_task(cfg.task))
    if resume_from is not None and "transport" in resume_from[1]:
        transport.load_state_dict(resume_from[1]["transport"])
    run = Run(cfg, run_dir, out, stop, ctx, learner, transport, last_saved=learner.iteration if resume_from else -1,
              keys=keys)
    try:
        _start_services(run, host, resume_from)
    except BaseException:
        _close(run)
        raise
    return run


def _start_services(run: Run, host: str, resume_from) -> None:
    """The sampler, the other learner replicas, then the actors (they ask the sampler for draws at once)."""
    cfg, ctx, out, transport, learner = run.cfg, run.ctx, run.out, run.transport, run.learner
    sampler_cfg = dataclasses.replace(
        cfg.sampler,
        host=host if host == "127.0.0.1" or ctx is None else "auto",
        seed=cfg.sampler.seed + cfg.seed,
        device=cfg.learner.device,
        port=cfg.port_base + 3 if cfg.port_base else cfg.sampler.port,
    )
    durations = task_clip_durations(cfg.task) if cfg.sampler.time_bin_s > 0 else None
    run.sampler = SamplerHandle.start(sampler_cfg, task_space(cfg.task), task_clips(cfg.task), ctx, keys=run.keys,
                                      durations=durations)
    if resume_from is not None and resume_from[1].get("sampler"):
        run.sampler.saved_state = checkpoint.from_checkpointable(resume_from[1]["sampler"])
        run.sampler.client.set_state(run.sampler.saved_state)
    replicas = ReplicaGroup.start(cfg, ctx, learner, host, run.run_dir)
    if replicas is not None:
        out.line(f"[morphmimic] {replicas.description}")
    endpoints = {**transport.endpoints, "sampler": run.sampler.endpoint}
    out.line(f"[morphmimic] run {run.run_dir} | mode {ctx.kind if ctx else 'serial'} | endpoints {endpoints}")
    transport.publish(learner.weights_msg())
    if ctx is None:
        run.pool = SerialActorPool(cfg, endpoints, keys=run.keys)
    else:
        run.pool = RayActorPool(cfg, endpoints, ctx, sampler_name=run.sampler.ray_name, keys=run.keys)
    run.health = HealthMonitor(transport.last_seen, cfg.stall_timeout_s, out.line)
    run.collector = Collector(transport, run.pool, cfg, run.stop, ctx is None, out)


def _iterate(run: Run, start_steps: int, start_time: float) -> dict[str, float] | None:
    """One policy iteration: batch, PPO update, publish, sampler exchange, metrics."""
    cfg, learner = run.cfg, run.learner
    t0 = time.monotonic()
    unrolls = run.collector.next_batch(learner.policy_version)
    if unrolls is None:
        return None
    t1 = time.monotonic()
    metrics = learner.update(unrolls)
    run.transport.publish(learner.weights_msg())
    t2 = time.monotonic()
    params, values = learner.value_pairs(unrolls, cfg.value_pairs_per_iteration)
    metrics.update(run.sampler.report_and_tick(params, values, learner.iteration, learner.take_clip_segments(),
                                               learner.take_clip_failures()))
    if cfg.vm_plot_every and learner.iteration % cfg.vm_plot_every == 0:
        run.sampler.plot(run.run_dir / "sampler_vm.png")
    run.health.check()
    metrics.update(_wire_metrics(run.transport, learner, run.pool))
    metrics.update(run.health.metrics())
    metrics["faults/actor_restarts"] = float(getattr(run.pool, "restarts", 0))
    metrics["faults/sampler_restores"] = float(run.sampler.restores)
    metrics["stats/learner_share"] = (t2 - t1) / max(time.monotonic() - t0, 1e-9)
    metrics["stats/update_s"] = t2 - t1
    metrics["stats/env_steps"] = float(learner.env_steps)
    rate = (learner.env_steps - start_steps) / max(time.monotonic() - start_time, 1e-9)
    metrics["charts/steps_per_s"] = rate
    eta = max(0, cfg.total_env_steps - learner.env_steps) / rate if rate > 0 else float("inf")
    run.out.iteration(learner.iteration, learner.env_steps, cfg.total_env_steps, rate, eta, metrics)
    return metrics


def _close(run: Run) -> None:
    """Stop actors and sampler, close sockets and logs, leave Ray: nothing left behind."""
    if run.pool is not None:
        try:
            (run.run_dir / "actors.json").write_text(json.dumps(run.pool.stats(), indent=2) + "\n")
        finally:
            run.pool.stop()
    if run.sampler is not None:
        run.sampler.stop()
    if run.learner.replicas is not None:
        run.learner.replicas.stop()
    run.transport.close()
    run.out.close()
    cluster.shutdown(run.ctx)
    run.stop.restore()


STOP_SIGNAL, STOP_BUDGET, STOP_ITERATIONS = "stopped by signal", "step budget reached", "iteration limit reached"


def train(cfg: RunConfig, on_iteration: Callable[[Run, dict[str, float]], None] | None = None) -> int:
    """Run training to the step budget (or iteration limit, or a stop signal); returns the exit
    code. `on_iteration(run, metrics)` is called after each iteration (benchmarks, fault tests)."""
    train_until_stop(cfg, on_iteration)
    return 0


def train_until_stop(cfg: RunConfig, on_iteration: Callable[[Run, dict[str, float]], None] | None = None) -> str:
    """`train`, returning why it stopped: STOP_SIGNAL (Ctrl-C, SIGTERM or a hook's request),
    STOP_BUDGET or STOP_ITERATIONS."""
    run = _start(cfg)
    try:
        learner = run.learner
        start_steps, start_time = learner.env_steps, time.monotonic()
        last = start_time
        try:
            while learner.env_steps < cfg.total_env_steps and not run.stop:
                if cfg.max_iterations and learner.iteration >= cfg.max_iterations:
                    break
                metrics = _iterate(run, start_steps, start_time)
                if metrics is None:
                    break
                now = time.monotonic()
                learner.train_seconds += now - last
                last = now
                if on_iteration is not None:
                    on_iteration(run, metrics)
                if learner.iteration % cfg.checkpoint_every == 0:
                    run.save()
        except Exception as exc:
            _save_on_crash(run, exc)
            raise
        try:
            _drain_at_stop(run)
        except Exception:  # the final checkpoint below matters more than the drain's count
            log.exception("draining the unroll socket at stop failed")
        run.transport.counters["unused_at_stop"] += len(run.collector.pending)
        if learner.iteration != run.last_saved:
            run.save()
        run.sampler.plot(run.run_dir / "sampler_vm.png")
        reason = (
            STOP_SIGNAL if run.stop
            else STOP_BUDGET if learner.env_steps >= cfg.total_env_steps
            else STOP_ITERATIONS
        )
        run.out.line(f"[morphmimic] {reason}: iteration {learner.iteration}, {learner.env_steps:,d} env steps; outputs in {run.run_dir}")
        return reason
    finally:
        _close(run)


def _save_on_crash(run: Run, exc: Exception) -> None:
    """An unexpected exception in the loop: write a checkpoint of the iterations done since the
    last one before the exception ends the process, so a crash loses none of them. NOTE: an
    exception inside the PPO update may leave that iteration's minibatch steps partly applied;
    the checkpoint keeps them, under the number of the last completed iteration."""
    if run.learner.iteration == run.last_saved:
        return
    run.out.line(f"[morphmimic] {type(exc).__name__} in the training loop at iteration {run.learner.iteration}: "
                 f"{exc}; writing a checkpoint before exiting")
    try:
        run.save()
    except Exception:  # the original exception is the one to report
        log.exception("could not write a checkpoint after the crash")


def _drain_at_stop(run: Run) -> None:
    """Tell the actors to stop, then read what they still send until each says it stopped (a
    final heartbeat carrying the last sequence number it used): drained unrolls are counted
    (`drained_at_stop`, `unused_at_stop`) and any tail an actor numbered but the learner never
    got becomes a counted gap, so nothing is left "in flight" at the end."""
    pool, transport, learner = run.pool, run.transport, run.learner
    if pool is None:
        return
    between = None
    if isinstance(pool, RayActorPool):
        expect = set(pool.runs)  # actors whose loop runs (or waits for Ray to restart them)
        for i in expect:
            try:
                pool.handles[i].stop.remote()
            except Exception as exc:  # noqa: BLE001 - an actor gone for good sends no final heartbeat
                log.warning("could not tell actor %d to stop: %s", i, exc)
    else:  # serial: the actors live here and send their final heartbeat between reads
        expect = set(range(len(pool.actors)))
        between = lambda: [a.finish() for a in pool.actors]
    drained = transport.drain(learner.policy_version, run.cfg.max_policy_lag, expect, between=between)
    missing = sorted(expect - transport.finals.keys())
    run.out.line(f"[morphmimic] drained {drained} unroll(s) at stop; lost unrolls (sequence gaps) "
                 f"{transport.lost()}" + (f"; no final word from actor(s) {missing}" if missing else ""))


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
        "faults/actor_sampler_outages": float(sum(transport.sampler_outages.values())),
    }
    for k, v in c.items():
        if k.startswith("rejected/"):
            out[f"wire/{k}"] = float(v)
    for reason, count in transport.snapshots.dropped.items():  # weights replies a peer did not take
        out[f"wire/snapshot_replies_dropped/{reason}"] = float(count)
    return out

