"""`train(cfg)`: the whole run. Joins or starts Ray (or none in serial mode), starts the sampler
service and the rollout actors, runs PPO iterations on the unrolls that stream in, publishes
weights, logs, checkpoints, and on the step budget, Ctrl-C or SIGTERM stops everything cleanly.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, NoReturn

import torch

from common.curve_keys import RunKeys
from common.tasks.registry import task_clip_durations, task_clips, task_space
from learner import checkpoint, cluster, fine_tune, run_progress
from learner.actor_pool import RayActorPool, SerialActorPool
from learner.collector import Collector
from learner.config import RunConfig
from learner.health import HealthMonitor
from learner.learner import Learner
from learner.replicas import ReplicaGroup
from learner.run_log import RunLog
from learner.scalar_sinks import open_sink
from learner.sampler_handle import SamplerHandle
from learner.signals import Interrupted, StopFlag
from learner.transport import LearnerTransport
from learner.unroll_bounds import UnrollBounds
from sampler import state_file as sampler_state_file

log = logging.getLogger(__name__)

def usage_error(message: str) -> NoReturn:
    """One line on stderr and exit code 2, as for any bad command-line value."""
    print(f"python -m learner.main: {message}", file=sys.stderr)
    raise SystemExit(2)


def find_resume(cfg: RunConfig) -> tuple[Path, tuple[Path, dict] | None, list[str]]:
    """The run directory (not created yet), the checkpoint to resume from per `cfg.resume`, and
    the lines to log about newer checkpoints `--resume auto` refused. A run whose checkpoints
    are all refused is a usage error: starting afresh would number new checkpoints below them."""
    run_dir = Path(cfg.runs_dir) / cfg.name
    ckpt_dir = run_dir / "ckpt"
    resume_from, notes = None, []
    if cfg.resume == "auto":
        resume_from, refused = checkpoint.load_newest_good(ckpt_dir)
        if refused and resume_from is None:
            usage_error(f"--resume auto: no checkpoint of {run_dir} is usable (newest: {refused[0]}); "
                        "move ckpt/ away, or use another --name")
        if refused:
            notes = [f"[morphmimic] --resume auto: {why}" for why in refused]
            notes.append(f"[morphmimic] --resume auto: falling back to {resume_from[0]}, the newest good checkpoint")
    elif cfg.resume == "never":
        if checkpoint.list_checkpoints(ckpt_dir):
            usage_error(f"run {run_dir} already has checkpoints; use --resume auto to continue it, or another --name")
    else:
        path = Path(cfg.resume)
        try:
            resume_from = (path, checkpoint.load(path))
        except checkpoint.CheckpointError as exc:
            usage_error(f"--resume {cfg.resume}: {exc}. Give a checkpoint directory, or auto, or never.")
    return run_dir, resume_from, notes


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


def fine_tuned_learner(cfg: RunConfig, learner: Learner) -> str:
    """Load `cfg.init_from`'s networks into the fresh `learner` (`learner.fine_tune`); the run
    log's line about it. A path that holds no checkpoint, or one of another task or network, is a
    usage error (exit 2) before anything is written."""
    try:
        path = checkpoint.resolve(cfg.init_from)
    except SystemExit:
        usage_error(f"--init-from {cfg.init_from}: no state.pt there, nor a run directory with ckpt/<iteration>/state.pt")
    try:
        state = checkpoint.load(path)
        source = RunConfig.from_json(str(state["config"]))
    except (checkpoint.CheckpointError, KeyError, ValueError) as exc:
        usage_error(f"--init-from {path}: not a usable training checkpoint ({type(exc).__name__}: {exc})")
    if source.task.name != cfg.task.name:
        usage_error(f"--init-from {path}: a checkpoint of task {source.task.name!r}; this run trains {cfg.task.name!r}")
    try:
        silenced = fine_tune.start_from(learner, state)
    except (RuntimeError, KeyError, ValueError, TypeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        usage_error(f"--init-from {path} does not fit task {cfg.task.name!r} with policy {cfg.policy.hidden} "
                    f"({type(exc).__name__}: {first}); give the network it was trained with")
    return fine_tune.describe(path, state, silenced)


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
    lost: dict[str, int] = field(default_factory=lambda: {"resumes": 0, "lost_iterations": 0, "lost_env_steps": 0})
    """What resumes cost the run: iterations and env steps a killed session did after its last
    checkpoint (from `progress.json`), summed over every resume."""

    def save(self, quick: bool = False) -> None:
        """Write a checkpoint of this iteration. `quick` (the stop path): the sampler gets one
        short try to hand over its state. A stop signal during the write is held until it ends."""
        self.stop.saving = True
        try:
            if quick:
                with self.sampler.quick():
                    self._save()
            else:
                self._save()
        finally:
            self.stop.saving = False

    def _save(self) -> None:
        state = self.learner.state_dict()
        state["transport"] = self.transport.state_dict()
        # NOTE: received (counted in `unrolls_received`) but not yet trained on: a session killed
        # after this checkpoint takes them with it; a resume counts them as `unused_at_resume`.
        state["transport"]["pending_unrolls"] = len(self.collector.pending) if self.collector else 0
        state["faults"] = self.fault_counters()
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

    def fault_counters(self) -> dict[str, dict[str, int]]:
        """Every counter family outside the learner's and the transport's own state, as a resumed
        run continues them (`faults/*`, `health/*`, the sampler handle's)."""
        out: dict[str, dict[str, int]] = {"run": dict(self.lost)}
        if self.pool is not None:
            out["pool"] = {"actor_restarts": int(self.pool.restarts)}
        if self.health is not None:
            out["health"] = self.health.state_dict()
        if self.sampler is not None:
            out["sampler"] = self.sampler.state_dict()
        return out

    def note_progress(self) -> None:
        """Rewrite `progress.json` (`learner.run_progress`): how far this run got, for a resumed one."""
        run_progress.write(self.run_dir, run_progress.Progress(self.learner.iteration, self.learner.env_steps,
                                                       float(self.sampler.taken_expected)))


def _start(cfg: RunConfig) -> Run:
    run_dir, resume_from, notes = find_resume(cfg)
    torch.set_num_threads(cfg.resolved_learner_threads)
    learner = resumed_learner(cfg, resume_from)
    if resume_from is None and cfg.init_from:
        notes.append(fine_tuned_learner(cfg, learner))
    run_dir.mkdir(parents=True, exist_ok=True)  # NOTE: only once the configuration and checkpoint are known good
    (run_dir / "config.json").write_text(cfg.to_json() + "\n")
    out = RunLog(run_dir, quiet=cfg.quiet, sink=open_sink(cfg.logger, run_dir, cfg.name, cfg))
    for note in notes:
        out.line(note)
    if resume_from is not None:
        out.line(f"[morphmimic] resumed {resume_from[0]} at iteration {learner.iteration}, {learner.env_steps:,d} env steps")
    # NOTE: `--resume auto` without a checkpoint still continues a run killed before its first one.
    reached = run_progress.read(run_dir) if resume_from is not None or cfg.resume == "auto" else None
    if resume_from is None:
        _forget_stale_sampler_state(run_dir, out)
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
        _start_services(run, host, resume_from, reached)
        if resume_from is not None or reached is not None:
            _continue_counters(run, resume_from[1] if resume_from else {}, reached)
    except BaseException:
        _close(run)
        raise
    return run


def _forget_stale_sampler_state(run_dir: Path, out: RunLog) -> None:
    """A run that starts afresh must not have its sampler restore the file of an earlier run
    that was killed before its first checkpoint."""
    stale = sampler_state_file.path_in(run_dir / "sampler")
    if stale.exists():
        stale.unlink()
        out.line(f"[morphmimic] removed {stale}: this run starts afresh, not from that sampler state")


def _continue_counters(run: Run, saved: dict, reached: run_progress.Progress | None) -> None:
    """A resumed run continues every counter family of its checkpoint, and counts the
    iterations and env steps the killed session did after it (`progress.json`) as lost. The
    checkpoint is rewritten at once when something was lost, so a second kill before the next
    checkpoint cannot make those counts vanish."""
    faults = saved.get("faults", {})
    run.pool.restarts += int(faults.get("pool", {}).get("actor_restarts", 0))
    run.health.load_state_dict(faults.get("health", {}))
    run.lost.update({k: int(v) for k, v in faults.get("run", {}).items()})
    run.lost["resumes"] += 1  # a session that continues a run: from a checkpoint, or from progress.json alone
    learner = run.learner
    if reached is None or reached.iteration <= learner.iteration:
        return
    iterations = reached.iteration - learner.iteration
    steps = max(0, reached.env_steps - learner.env_steps)
    per_unroll = run.cfg.actors.unroll_length * run.cfg.actors.envs_per_actor
    run.transport.resume_allowance += -(-steps // per_unroll)
    run.lost["lost_iterations"] += iterations
    run.lost["lost_env_steps"] += steps
    run.out.line(f"[morphmimic] the killed session had reached iteration {reached.iteration} ({reached.env_steps:,d} env "
                 f"steps): {iterations} iteration(s), {steps:,d} env steps lost (faults/lost_iterations, faults/lost_env_steps)")
    run.note_progress()
    run.save()


def _start_services(run: Run, host: str, resume_from, reached: run_progress.Progress | None = None) -> None:
    """The sampler, the other learner replicas, then the actors (they ask the sampler for draws at once)."""
    cfg, ctx, out, transport, learner = run.cfg, run.ctx, run.out, run.transport, run.learner
    sampler_cfg = dataclasses.replace(
        cfg.sampler,
        host=host if host == "127.0.0.1" or ctx is None else "auto",
        seed=cfg.sampler.seed + cfg.seed,
        device=cfg.learner.device,
        port=cfg.port_base + 3 if cfg.port_base else cfg.sampler.port,
        # NOTE: the sampler keeps its own state file where it runs: on this machine, the run's folder.
        state_dir=cfg.sampler.state_dir or (str(run.run_dir / "sampler") if host == "127.0.0.1" else ""),
    )
    durations = task_clip_durations(cfg.task) if cfg.sampler.time_bin_s > 0 else None
    run.sampler = SamplerHandle.start(sampler_cfg, task_space(cfg.task), task_clips(cfg.task), ctx, keys=run.keys,
                                      durations=durations)
    if resume_from is not None:
        run.sampler.load_state_dict(resume_from[1].get("faults", {}).get("sampler", {}),
                                    taken_since=reached.sampler_pairs_taken if reached else 0.0)
        if resume_from[1].get("sampler"):
            out.line("[morphmimic] " + run.sampler.restore_at_start(checkpoint.from_checkpointable(resume_from[1]["sampler"])))
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
    params, values, pair_clips = learner.value_triples(unrolls, cfg.value_pairs_per_iteration)
    with run.sampler.quick() if run.stop else contextlib.nullcontext():  # stopping: no long sampler timeouts
        metrics.update(run.sampler.report_and_tick(params, values, learner.iteration, learner.take_clip_segments(),
                                                   learner.take_clip_failures(), pair_clips=pair_clips))
    if cfg.vm_plot_every and learner.iteration % cfg.vm_plot_every == 0:
        run.sampler.plot(run.run_dir / "sampler_vm.png")
    run.health.check()
    metrics.update(_wire_metrics(run.transport, learner, run.pool))
    metrics.update(run.health.metrics())
    metrics["faults/actor_restarts"] = float(run.pool.restarts)
    metrics.update(run.sampler.counters())
    metrics.update({f"faults/{k}": float(v) for k, v in run.lost.items()})
    metrics["stats/learner_share"] = (t2 - t1) / max(time.monotonic() - t0, 1e-9)
    metrics["stats/update_s"] = t2 - t1
    metrics["stats/env_steps"] = float(learner.env_steps)
    rate = (learner.env_steps - start_steps) / max(time.monotonic() - start_time, 1e-9)
    metrics["charts/steps_per_s"] = rate
    eta = max(0, cfg.total_env_steps - learner.env_steps) / rate if rate > 0 else float("inf")
    run.out.iteration(learner.iteration, learner.env_steps, cfg.total_env_steps, rate, eta, metrics)
    return metrics


def _close(run: Run, quick: bool = False) -> None:
    """Stop actors and sampler, close sockets and logs, leave Ray: nothing left behind. `quick`
    (after a stop signal): Ray's waits are 5 s instead of 30 s and 15 s."""
    if run.pool is not None:
        try:
            stats = run.pool.stats(timeout_s=5.0 if quick else 30.0)
            (run.run_dir / "actors.json").write_text(json.dumps(stats, indent=2) + "\n")
        finally:
            run.pool.stop(timeout_s=5.0 if quick else 15.0)
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
        interrupted = False
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
                run.note_progress()
                if on_iteration is not None:
                    on_iteration(run, metrics)
                if learner.iteration % cfg.checkpoint_every == 0:
                    run.save()
        except Interrupted:  # a second signal: the iteration was cut short; checkpoint now
            interrupted = True
        except Exception as exc:
            _save_on_crash(run, exc)
            raise
        _stop_and_save(run, interrupted)
        reason = (
            STOP_SIGNAL if run.stop
            else STOP_BUDGET if learner.env_steps >= cfg.total_env_steps
            else STOP_ITERATIONS
        )
        run.out.line(f"[morphmimic] {reason}: iteration {learner.iteration}, {learner.env_steps:,d} env steps; outputs in {run.run_dir}")
        return reason
    finally:
        _close(run, quick=bool(run.stop.signal_name))


def _stop_and_save(run: Run, interrupted: bool) -> None:
    """Drain the actors, hand the sampler what is queued, and write the final checkpoint. After a
    stop signal every step has a short bound (drain 3 s, sampler 1 s) so the checkpoint is on
    disk within seconds whatever the sockets are doing; after a second signal (`interrupted`)
    the drain is skipped. NOTE: a second signal during the PPO update may leave that
    iteration's minibatch steps partly applied; the checkpoint keeps them, as after a crash."""
    signalled = interrupted or bool(run.stop.signal_name)
    hurry = run.sampler.quick() if signalled else contextlib.nullcontext()
    try:
        if not interrupted:
            _drain_at_stop(run, quick=signalled)
    except Interrupted:
        pass
    except Exception:  # the final checkpoint below matters more than the drain's count
        log.exception("draining the unroll socket at stop failed")
    try:
        with hurry:
            run.sampler.flush()
    except Interrupted:
        pass
    try:
        with run.stop.held():
            run.transport.counters["unused_at_stop"] += len(run.collector.pending)
            run.collector.pending.clear()  # counted: the final checkpoint must not count them again at a resume
    except Interrupted:
        pass
    run.save(quick=signalled)  # NOTE: always: the drain's counts belong in it even at a saved iteration
    try:
        with run.sampler.quick() if signalled else contextlib.nullcontext():
            run.sampler.plot(run.run_dir / "sampler_vm.png")
    except Interrupted:
        pass


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


def _drain_at_stop(run: Run, quick: bool = False) -> None:
    """Tell the actors to stop, then read what they still send until each says it stopped (a
    final heartbeat carrying the last sequence number it used): drained unrolls are counted
    (`drained_at_stop`, `unused_at_stop`) and any tail an actor numbered but the learner never
    got becomes a counted gap, so nothing is left "in flight" at the end. `quick` (a stop
    signal): at most 3 s, 1 s of quiet."""
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
    bounds = {"quiet_s": 1.0, "max_s": 3.0} if quick else {}
    drained = transport.drain(learner.policy_version, run.cfg.max_policy_lag, expect, between=between,
                              hold=run.stop.held, **bounds)
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
        "wire/late_unrolls": float(c["late_unrolls"]),
        "wire/rejected": float(rejected),
        "wire/bytes_received": float(transport.bytes_received),
        "wire/snapshots_served": float(c["snapshots_served"]),
        "stats/divergences": float(learner.counters["divergences"]),
        "stats/actors_alive": float(pool.alive()),
        "faults/actor_sampler_outages": float(transport.sampler_outages_total()),
        "wire/disconnects": float(c["disconnects"]),
    }
    for k, v in c.items():
        if k.startswith("rejected/"):
            out[f"wire/{k}"] = float(v)
        elif k.startswith("lost/"):  # work a killed session took with it (`transport.resume_marks`)
            out[f"faults/{k[5:]}"] = float(v)
    for reason, count in transport.snapshots.dropped.items():  # weights replies a peer did not take
        out[f"wire/snapshot_replies_dropped/{reason}"] = float(count)
    return out

