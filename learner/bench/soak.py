"""`morphmimic bench soak --minutes N`: train on the local two-worker test cluster for N minutes
while injecting every kind of fault, then train a clean run of the same length (env steps) with
the same command, and report load held, faults survived, losses counted and uncounted, and the
final returns side by side (docs/soak.md).

The learner runs as its own process (soak_learner.py), so that it can be SIGKILLed like any
crashed learner: inside it, a hook injects the in-process faults (soak_faults.py: actors killed
and stalled, hostile bytes, the sampler killed, a poisoned unroll, forged counters, a slow reader
on each ROUTER); from here come the learner kill with `--resume auto` and the NaN checkpoint
(a checkpoint whose weights are NaN written as the newest before the learner resumes). A learner
that stops iterating for `--stall-limit` seconds is killed and resumed (the stall is reported);
every wait here is bounded. Not a test (it runs for minutes; tests/learner/bench/test_soak.py
runs a short one); loopback only.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from common.config_limits import SEED, Limit, above, check_limits, validated
from learner.bench.soak_faults import IN_PROCESS_KINDS
from learner.bench.soak_report import SoakRecord, report
from learner.cli_options import parse_options
from learner.presets import check_presets

PROG = "morphmimic bench soak"
OUTSIDE_KINDS = ("learner_kill", "nan_checkpoint")
KINDS = IN_PROCESS_KINDS + OUTSIDE_KINDS
START_S = 240.0
"""Longest the first learner process may take to its first iteration; later ones get twice what it took."""
SURVIVE_ITERATIONS = 2
"""A resumed learner survived its kill once it finished this many iterations with finite losses."""
MAX_RESTARTS = 8
SETTLE_S = 20.0
"""Once every kind has come, the soak goes on at least this long (the last faults are judged)."""
DRAIN_S = 60.0
"""Extra time a stopping learner may take for its drain and last checkpoint."""


@validated
@dataclass
class SoakBenchOptions:
    minutes: float = 10.0
    """How long to train under faults (then a clean run of the same env steps)."""
    preset: str = "reach"
    """Training preset."""
    fault_every: float = 8.0
    """Seconds between two in-process faults."""
    faults: tuple[str, ...] = KINDS
    """Fault kinds to inject (all by default)."""
    clean: bool = True
    """Train the clean run to compare the return with (--no-clean: skip it)."""
    stall_limit: float = 90.0
    """A learner with no iteration for this many seconds is killed and resumed (the stall is reported)."""
    seed: int = 0
    """Seed of the faults and of both runs."""

    LIMITS: ClassVar[dict[str, Limit]] = {"minutes": above(0), "fault_every": above(0), "stall_limit": above(0),
                                          "seed": SEED}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_presets("--preset", [self.preset])
        check_limits(self)
        for kind in self.faults:
            if kind not in KINDS:
                raise ValueError(f"--faults {kind!r} is not a fault kind; choose from {', '.join(KINDS)}")


@dataclass
class _Learner:
    """One learner process and its status file."""

    proc: subprocess.Popen
    status: Path
    started: float

    def read(self) -> dict:
        try:
            return json.loads(self.status.read_text())
        except (OSError, ValueError):
            return {}


class Soak:
    def __init__(self, args: SoakBenchOptions, address: str, work: Path):
        self.args, self.address, self.work = args, address, work
        self.rec = SoakRecord(args.minutes)
        self.segment = 0

    def _spawn(self, name: str, resume: str, total_steps: int, faults: bool) -> _Learner:
        self.segment += 1
        status = self.work / f"status-{name}-{self.segment}.json"
        control = self.work / f"control-{name}"
        control.mkdir(exist_ok=True)
        kinds = self._kinds_first_unseen() if faults else []
        spec = {"preset": self.args.preset, "runs_dir": str(self.work / "runs"), "name": name, "ray_address": self.address,
                "resume": resume, "total_env_steps": total_steps, "seed": self.args.seed + self.segment,
                "fault_every_s": self.args.fault_every if kinds else 0.0, "kinds": kinds, "status": str(status),
                "control": str(control)}
        spec_path = self.work / f"spec-{self.segment}.json"
        spec_path.write_text(json.dumps(spec))
        with open(self.work / f"learner-{self.segment}.log", "w") as log:
            env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
            proc = subprocess.Popen([sys.executable, "-m", "learner.bench.soak_learner", str(spec_path)], stdout=log,
                                    stderr=subprocess.STDOUT, env=env, cwd=Path(__file__).resolve().parents[2])
        print(f"[soak] learner process {proc.pid} ({name}, resume {resume})", flush=True)
        return _Learner(proc, status, time.monotonic())

    def _ckpt_dir(self) -> Path:
        return self.work / "runs" / "soak" / "ckpt"

    def _write_nan_checkpoint(self) -> Path | None:
        """The newest checkpoint again, one iteration on, with every weight NaN."""
        import torch  # lazy: heavy (torch), only when this fault is injected

        from learner import checkpoint  # lazy: imports torch

        latest = checkpoint.load_latest(self._ckpt_dir())
        if latest is None:
            return None
        _, state = latest
        for net in ("policy", "value"):
            state[net] = {k: torch.full_like(v, float("nan")) if torch.is_floating_point(v) else v for k, v in state[net].items()}
        state["iteration"] += 1
        return checkpoint.save(self._ckpt_dir(), state["iteration"], state, keep=10)

    def _last_lines(self, n: int = 1) -> str:
        log = self.work / f"learner-{self.segment}.log"
        lines = [l for l in log.read_text(errors="replace").splitlines() if l.strip()] if log.exists() else []
        return " | ".join(lines[-n:])[:300]

    def _kinds_first_unseen(self) -> list[str]:
        """The in-process kinds to inject, those not injected yet first."""
        seen = {f["kind"] for st in self.rec.segments for f in st.get("faults", [])}
        kinds = [k for k in self.args.faults if k in IN_PROCESS_KINDS]
        return [k for k in kinds if k not in seen] + [k for k in kinds if k in seen]

    def _inject_outside(self, kind: str, learner: _Learner) -> dict:
        """SIGKILL the learner (and for nan_checkpoint poison its newest checkpoint); the fault's record."""
        learner.proc.send_signal(signal.SIGKILL)
        learner.proc.wait(timeout=30)
        last = learner.read()
        self.rec.segments.append(last)
        fault = {"kind": kind, "at": time.time(), "outcome": "unjudged"}
        if not last.get("losses_finite", True):
            fault["outcome"] = "unjudged: the losses were non-finite already when it came"
        if kind == "nan_checkpoint":
            written = self._write_nan_checkpoint()
            if written is None:
                fault["outcome"] = "failed: no checkpoint to poison"
            else:
                (written / "NAN").write_text("written by the soak\n")
        print(f"[soak] injected {kind} (learner {learner.proc.pid} SIGKILLed)", flush=True)
        self.rec.outside.append(fault)
        return fault

    def run_faulted(self) -> None:
        """Train under faults for `--minutes` from the first iteration (longer, up to 3x, until
        every kind has come once); then the learner is told to stop (a final status with the
        accounting). A learner that exits or wedges is killed and resumed, once more past the
        deadline, so that the run still ends with a clean stop."""
        args = self.args
        control = self.work / "control-soak"
        outside = [k for k in OUTSIDE_KINDS if k in args.faults]
        t0, end, last_call, all_in, deadline, plan, startup_s = time.time(), None, 0.0, None, float("inf"), [], None
        learner = self._spawn("soak", "never", 10**12, faults=True)
        last_iter, last_progress, judging, restarts, final_attempt, shown = -1, time.monotonic(), None, 0, False, 0
        while True:
            time.sleep(0.5)
            st, now = learner.read(), time.monotonic()
            mine = st.get("pid") == learner.proc.pid
            if end is not None:
                self.rec.longest_stall_s = max(self.rec.longest_stall_s, now - last_progress)
            for f in st.get("faults", [])[shown:] if mine else []:
                print(f"[soak] iteration {f['iteration']}: injected {f['kind']}", flush=True)
            shown = len(st.get("faults", [])) if mine else shown
            if mine and st.get("iteration", -1) != last_iter:
                if last_iter < 0:
                    print(f"[soak] learner {learner.proc.pid}: first iteration after {now - learner.started:.0f} s", flush=True)
                    startup_s = now - learner.started if startup_s is None else startup_s
                if end is None:  # the soak's clock starts with the first iteration (start-up is not load)
                    end, last_call = time.time() + 60 * args.minutes, time.time() + 3 * 60 * args.minutes
                    plan = [(time.time() + 60 * args.minutes * (i + 1) / (len(outside) + 1), k) for i, k in enumerate(outside)]
                last_iter, last_progress = st["iteration"], now
                if judging is not None and not st.get("losses_finite", True):
                    judging["outcome"] = f"failed: non-finite losses at iteration {st['iteration']} after the resume"
                    judging = None
                elif judging is not None and st["iteration"] >= st.get("first_iteration", st["iteration"]) + SURVIVE_ITERATIONS:
                    judging["outcome"] = "survived"
                    judging = None
            seen = {f["kind"] for seg in [*self.rec.segments, st if mine else {}] for f in seg.get("faults", [])}
            first_round = all(k in seen for k in args.faults if k in IN_PROCESS_KINDS)  # every in-process kind came once
            if end is not None and not plan and judging is None and first_round and all_in is None:
                all_in = time.time()
            if end is not None:  # a slow machine gets more time (up to 3x) until every kind has come once
                deadline = max(end, all_in + SETTLE_S + 2 * args.fault_every) if all_in is not None else last_call
                if time.time() > deadline - max(2 * args.fault_every, 8.0):
                    (control / "quiet").touch()
                if time.time() > deadline:
                    (control / "stop").touch()
            code = learner.proc.poll()
            if code is not None and mine and st.get("final"):
                self.rec.segments.append(st)
                break
            if last_iter >= 0:  # after the stop, the drain and the last checkpoint may take a while
                wedged = now - last_progress > args.stall_limit + (DRAIN_S if (control / "stop").exists() else 0.0)
            else:  # not iterating yet: twice the first learner's start-up on this machine, at least --stall-limit
                wedged = now - learner.started > (START_S if startup_s is None else max(args.stall_limit, 2 * startup_s))
            if code is not None or wedged:
                quiet_for = now - (last_progress if last_iter >= 0 else learner.started)
                why = f"exited {code}: {self._last_lines()}" if code is not None else f"no iteration for {quiet_for:.0f} s"
                print(f"[soak] learner process {learner.proc.pid} {why}", flush=True)
                if learner.proc.poll() is None:
                    learner.proc.kill()
                    learner.proc.wait(timeout=30)
                self.rec.segments.append(st if mine else {})
                if judging is not None:
                    judging["outcome"] = f"failed: the resumed learner {why}"
                    judging = None
                for marker in self._ckpt_dir().glob("*/NAN"):  # the operator's move: drop the poisoned checkpoint
                    _remove_checkpoint(marker.parent)
                restarts += 1
                if restarts > MAX_RESTARTS or final_attempt or end is None:
                    break
                final_attempt = time.time() > deadline  # past the deadline: one resume more, for the final accounting
                learner = self._spawn("soak", "auto", 10**12, faults=True)
                last_iter, shown = -1, 0  # NOTE: not last_progress: the stall goes on until the new learner iterates
                continue
            due = bool(plan) and time.time() >= plan[0][0] and first_round and judging is None and time.time() < deadline - 5
            if due:
                (control / "hold").touch()  # the in-process faults pause, so that the pending ones are judged first
            ready = due and mine and st["iteration"] >= st.get("first_iteration", 0) + SURVIVE_ITERATIONS and st.get("last_saved", -1) >= 0
            if ready and not (any(f["outcome"] == "unjudged" for f in st.get("faults", [])) and time.time() < plan[0][0] + 20):
                judging = self._inject_outside(plan.pop(0)[1], learner)
                if judging["outcome"] != "unjudged":
                    judging = None
                (control / "hold").unlink()
                learner = self._spawn("soak", "auto", 10**12, faults=True)
                last_iter, shown = -1, 0
        self.rec.wall_s = time.time() - t0
        if judging is not None:
            judging["outcome"] = "unjudged: the soak ended first"
        self.rec.not_injected = [k for _, k in plan]

    def run_clean(self) -> None:
        """The same command without faults, to the env steps the faulted run reached."""
        final = self.rec.segments[-1] if self.rec.segments else {}
        steps = int(final.get("env_steps", 0))
        if steps <= 0:
            return
        t0 = time.time()
        learner = self._spawn("clean", "never", steps, faults=False)
        try:
            learner.proc.wait(timeout=3 * 60 * self.args.minutes + 2 * START_S)
        except subprocess.TimeoutExpired:
            learner.proc.kill()
            learner.proc.wait(timeout=30)
        st = learner.read()
        if st.get("final"):
            st["wall_s"] = time.time() - t0
            self.rec.clean = st
        else:
            print(f"[soak] the clean run did not finish: {self._last_lines()}", flush=True)


def _remove_checkpoint(path: Path) -> None:
    for p in sorted(path.rglob("*"), reverse=True):
        if p.is_dir():
            p.rmdir()
        else:
            p.unlink()
    path.rmdir()


def main(argv: list[str]) -> int:
    args = parse_options(SoakBenchOptions, argv, prog=PROG, description=__doc__)

    from learner.cluster import start_test_cluster  # lazy: heavy (ray), after parsing so --help is fast

    cluster = start_test_cluster(rollout_per_worker=1, cpus_per_worker=1)
    try:
        with tempfile.TemporaryDirectory(prefix="soak-") as tmp:
            soak = Soak(args, cluster.address, Path(tmp))
            soak.run_faulted()
            if args.clean:
                soak.run_clean()
            ok = report(soak.rec)
            return 0 if ok else 1
    finally:
        cluster.shutdown()
