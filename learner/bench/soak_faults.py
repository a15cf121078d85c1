"""The faults `morphmimic bench soak` injects from inside a training learner (its `on_iteration`
hook, where the run's actors, sockets, keys and sampler are at hand), each a function of the
`Run` and a random generator, and whether training survived each.

    kill_actor        a rollout actor's process SIGKILLed (Ray restarts it)
    stall_actor       an actor hangs 2-12 s (no unrolls, no heartbeats)
    garbage_learner   random bytes on the unroll PULL and the weights ROUTER, from an insider
                      (the run's actor keys) or an outsider (no keys: the CURVE handshake)
    garbage_sampler   the same on the sampler's ROUTER
    sampler_outage    the sampler actor killed through Ray (Ray restarts it)
    sampler_kill      the sampler's process SIGKILLed
    poison_unroll     a well-formed unroll from an insider, as a real actor's next one, with
                      observations and rewards of 1e30 (finite, so the codec passes them)
    forged_counters   an insider's forged bookkeeping as a real actor: a heartbeat claiming
                      seq 2^53, an unroll spoofing seq 0, an unroll claiming 2^53 divergences
    slow_reader       on each ROUTER (weights, sampler), a peer that sends 3000 requests and never
                      reads a reply, held open 8 s
The learner kill, with resume, and the NaN checkpoint come from outside (soak.py).

Survival: a fault is survived once the learner has finished `SURVIVE_ITERATIONS` more
iterations with finite losses after it; a non-finite loss after it, before that, fails it;
a fault too recent to judge at the stop, or one that came when the losses were non-finite
already, is "unjudged". The 2^53 figures are the codec's
ceiling for an int (`wire.MAX_INT`).
"""

from __future__ import annotations

import collections
import math
import os
import signal
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import zmq

from common import curve_keys, wire

IN_PROCESS_KINDS = ("kill_actor", "stall_actor", "garbage_learner", "garbage_sampler", "sampler_outage",
                    "sampler_kill", "poison_unroll", "forged_counters", "slow_reader")
SURVIVE_ITERATIONS = 2
MAX_PER_ITERATION = 3
SLOW_READER_REQUESTS = 3000
SLOW_READER_HOLD_S = 8.0
POISON = 1e30


def losses_finite(metrics: dict[str, float]) -> bool:
    """Every `losses/*` metric of an iteration is finite (explained variance included: NaN there
    means the value targets are broken)."""
    return all(math.isfinite(v) for k, v in metrics.items() if k.startswith("losses/"))


def _push(endpoint: str, keys, frames_list: list[list]) -> None:
    """Send messages on the unroll channel as an insider holding `keys` (the run's actor keys)."""
    sock = zmq.Context.instance().socket(zmq.PUSH)
    curve_keys.make_client(sock, keys, curve_keys.ACTOR)
    sock.setsockopt(zmq.LINGER, 2000)
    sock.setsockopt(zmq.SNDTIMEO, 2000)
    sock.connect(endpoint)
    try:
        for frames in frames_list:
            sock.send_multipart(frames, copy=False)
    finally:
        sock.close()


def _unroll(run, actor_id: int, seq: int, value: float = 0.0, divergences: int = 0) -> list:
    d = run.transport.dims
    T, N = d["T"], d["N"]
    f = lambda *shape: np.full(shape, value, np.float32)  # noqa: E731
    msg = wire.UnrollMsg(
        actor_id=actor_id, seq=seq, policy_version=run.learner.policy_version,
        obs=f(T, N, d["obs_dim"]), next_obs=f(T, N, d["obs_dim"]), actions=np.zeros((T, N, d["act_dim"]), np.float32),
        logp=np.zeros((T, N), np.float32), rewards=f(T, N), terminated=np.zeros((T, N), bool),
        truncated=np.zeros((T, N), bool), params=np.zeros((T, N, d["n_params"]), np.float32), divergences=divergences,
    )
    return wire.encode(msg)


def _sampler_endpoint(run) -> str:
    import ray  # lazy: heavy (ray), only the soak's learner reaches the sampler through it

    return ray.get(run.sampler.ray_handle.endpoint.remote(), timeout=10)


def _garbage(endpoint: str, router: bool, keys, rng: np.random.Generator) -> None:
    """Random bytes from an insider (keys: the codec refuses them) or an outsider (no keys: the
    CURVE handshake refuses it)."""
    sock = zmq.Context.instance().socket(zmq.DEALER if router else zmq.PUSH)
    curve_keys.make_client(sock, keys, curve_keys.ACTOR)
    sock.setsockopt(zmq.LINGER, 500)
    sock.connect(endpoint)
    junk = [bytes(rng.integers(0, 256, size=int(rng.integers(1, 200)), dtype=np.uint8))]
    sock.send_multipart([b"", *junk] if router else junk)
    if router:
        sock.poll(2000)
    sock.close()


def _slow_reader(endpoint: str, keys, request: list) -> None:
    """A peer that asks and never reads: `SLOW_READER_REQUESTS` requests, then silence for
    `SLOW_READER_HOLD_S` with the replies piling up, then it leaves (runs on its own thread)."""
    sock = zmq.Context.instance().socket(zmq.DEALER)
    curve_keys.make_client(sock, keys, curve_keys.ACTOR)
    sock.setsockopt(zmq.RCVHWM, 1)
    sock.setsockopt(zmq.RCVBUF, 4096)
    sock.setsockopt(zmq.SNDHWM, SLOW_READER_REQUESTS)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(endpoint)
    try:
        for _ in range(SLOW_READER_REQUESTS):
            sock.send_multipart([b"", *request], flags=zmq.NOBLOCK, copy=True)
    except zmq.Again:
        pass
    time.sleep(SLOW_READER_HOLD_S)
    sock.close()


@dataclass
class Fault:
    kind: str
    iteration: int
    at: float
    """time.time() of the injection."""
    outcome: str = "unjudged"
    """survived | failed: <why> | unjudged: <why> (too recent at the stop, or the learner's losses
    were non-finite already when it came: an earlier fault's doing, not this one's)."""


@dataclass
class InProcessFaults:
    """The hook's state: which faults were injected when, and how each turned out."""

    rng: np.random.Generator
    every_s: float
    """Seconds between two faults."""
    kinds: tuple[str, ...] = IN_PROCESS_KINDS
    faults: list[Fault] = field(default_factory=list)
    not_injected: collections.Counter = field(default_factory=collections.Counter)
    why_not: dict[str, str] = field(default_factory=dict)
    """The last reason each kind could not be injected."""
    threads: list[threading.Thread] = field(default_factory=list)
    _order: list[str] = field(default_factory=list)
    _rounds: int = 0
    quiet: bool = False
    """Set: no faults for now (the soak's end is near, or an outside fault is about to come: the
    pending ones must be judged first)."""
    _next_at: float | None = None

    def _next_kind(self) -> str:
        """Every kind once in the order given (the soak puts the kinds not injected yet first),
        then each round in a random order: a short soak still sees every kind."""
        if not self._order:
            self._order = list(self.kinds) if not self._rounds else [str(k) for k in self.rng.permutation(list(self.kinds))]
            self._rounds += 1
        return self._order.pop(0)

    def judge(self, iteration: int, metrics: dict[str, float]) -> None:
        finite = losses_finite(metrics)
        open_ = [f for f in self.faults if f.outcome == "unjudged"]
        for f in open_:
            if not finite:  # NOTE: with several faults in the window, which one did it is not known
                f.outcome = f"failed: non-finite losses at iteration {iteration}" + (
                    f" (or one of the {len(open_) - 1} other fault(s) then pending)" if len(open_) > 1 else "")
            elif iteration >= f.iteration + SURVIVE_ITERATIONS:
                f.outcome = "survived"

    def __call__(self, run, metrics: dict[str, float]) -> None:
        """After an iteration: judge, then inject the faults due since the last call (iterations
        may be slower than `every_s`; at most `MAX_PER_ITERATION` at once)."""
        self.judge(run.learner.iteration, metrics)
        now = time.time()
        if self._next_at is None:  # the first iteration: the clock starts now, not at start-up
            self._next_at = now + self.every_s
        due = 0
        while self.kinds and not self.quiet and now >= self._next_at and due < MAX_PER_ITERATION:
            self._next_at += self.every_s
            due += 1
        self._next_at = max(self._next_at, now)
        for _ in range(due):
            self._inject(self._next_kind(), run, metrics)

    def _inject(self, kind: str, run, metrics: dict[str, float]) -> None:
        try:
            INJECT[kind](self, run)
        except Exception as exc:  # noqa: BLE001 - the target was down (e.g. restarting): not injected, tried again next
            self.not_injected[kind] += 1
            self.why_not[kind] = f"{type(exc).__name__}: {str(exc)[:160]}"
            self._order.insert(0, kind)
            print(f"[soak] {kind} not injected: {type(exc).__name__}: {exc}", flush=True)
            return
        fault = Fault(kind, run.learner.iteration, time.time())
        if not losses_finite(metrics):
            fault.outcome = "unjudged: the losses were non-finite already when it came"
        self.faults.append(fault)
        print(f"[soak] iteration {run.learner.iteration}: injected {kind}", flush=True)

    def close(self) -> None:
        for t in self.threads:
            t.join(timeout=SLOW_READER_HOLD_S + 5)

    # ---- the injectors ----

    def _actor(self, run) -> tuple[int, object]:
        i = int(self.rng.integers(len(run.pool.handles)))
        return i, run.pool.handles[i]

    def kill_actor(self, run) -> None:
        import ray  # lazy: heavy (ray), the soak's learner only

        _, handle = self._actor(run)
        os.kill(ray.get(handle.stats.remote(), timeout=10)["pid"], signal.SIGKILL)

    def stall_actor(self, run) -> None:
        _, handle = self._actor(run)
        handle.stall.remote(float(self.rng.uniform(2, 12)))

    def _insider(self, run):
        return run.keys.for_actors() if run.keys is not None else None

    def garbage_learner(self, run) -> None:
        keys = self._insider(run) if self.rng.random() < 0.5 else None
        _garbage(run.transport.endpoints["unrolls"], router=False, keys=keys, rng=self.rng)
        _garbage(run.transport.endpoints["weights_router"], router=True, keys=keys, rng=self.rng)

    def garbage_sampler(self, run) -> None:
        keys = self._insider(run) if self.rng.random() < 0.5 else None
        _garbage(_sampler_endpoint(run), router=True, keys=keys, rng=self.rng)

    def sampler_outage(self, run) -> None:
        import ray  # lazy: heavy (ray), the soak's learner only

        ray.kill(run.sampler.ray_handle, no_restart=False)

    def sampler_kill(self, run) -> None:
        import ray  # lazy: heavy (ray), the soak's learner only

        pid = ray.get(run.sampler.ray_handle.__ray_call__.remote(lambda _self: os.getpid()), timeout=10)
        os.kill(pid, signal.SIGKILL)

    def poison_unroll(self, run) -> None:
        a, _ = self._actor(run)
        seq = run.transport.last_seq.get(a, -1) + 1
        _push(run.transport.endpoints["unrolls"], self._insider(run), [_unroll(run, a, seq, value=POISON)])

    def forged_counters(self, run) -> None:
        a, _ = self._actor(run)
        beat = wire.encode(wire.HeartbeatMsg(actor_id=a, seq=wire.MAX_INT, env_steps=wire.MAX_INT))
        spoof = _unroll(run, a, 0)
        diverged = _unroll(run, a, run.transport.last_seq.get(a, -1) + 1, divergences=wire.MAX_INT)
        _push(run.transport.endpoints["unrolls"], self._insider(run), [spoof, diverged, beat])

    def slow_reader(self, run) -> None:
        keys = self._insider(run)
        targets = [(run.transport.endpoints["weights_router"], wire.encode(wire.WeightsRequestMsg(actor_id=0))),
                   (_sampler_endpoint(run), wire.encode(wire.DrawRequestMsg(n=64)))]
        for endpoint, request in targets:
            request = [bytes(f) for f in request]
            t = threading.Thread(target=_slow_reader, args=(endpoint, keys, request), name="soak-slow-reader", daemon=True)
            t.start()
            self.threads.append(t)


INJECT: dict[str, Callable[[InProcessFaults, object], None]] = {k: getattr(InProcessFaults, k) for k in IN_PROCESS_KINDS}
