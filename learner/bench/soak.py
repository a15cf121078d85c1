"""`morphmimic bench soak --minutes N`: train on the local two-worker test cluster while
injecting faults at random (actor processes SIGKILLed, actors stalled, hostile bytes on the
learner's and the sampler's sockets, the sampler silenced and restarted), then account for
every unroll.

Ground truth comes from the actors' durable sequence ledgers (`actors/seq_ledger.py`): every
unroll an actor numbered was either received by the learner, counted as a sequence gap (lost
in flight, e.g. queued in a killed process), or still in flight when the run stopped. Every
received unroll was either trained on, dropped as stale (counted), or left unused at the stop
(counted). "lost uncounted" is what these identities cannot explain and must be 0.
Not a test (it runs for minutes); loopback only.
"""

from __future__ import annotations

import collections
import dataclasses
import os
import signal
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import zmq

from common import curve_keys
from common.config_limits import SEED, Limit, above, between, check_limits, validated
from learner.cli_options import parse_options
from learner.cluster import start_test_cluster as start
from learner.presets import PRESETS, check_presets


def _ledger(run_dir: Path) -> dict[int, int]:
    out = {}
    for p in (run_dir / "ledger").glob("actor-*.seq"):
        raw = p.read_text().strip("\0 \n")
        out[int(p.stem.split("-")[1])] = int(raw) + 1 if raw else 0
    return out


PROG = "morphmimic bench soak"


@validated
@dataclass
class SoakBenchOptions:
    minutes: float = 10.0
    """How long to train under faults."""
    preset: str = "reach"
    """Training preset."""
    fault_rate: float = 0.25
    """Probability of a fault per iteration."""
    seed: int = 0
    """Seed of the faults."""

    LIMITS: ClassVar[dict[str, Limit]] = {"minutes": above(0), "fault_rate": between(0, 1), "seed": SEED}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_presets("--preset", [self.preset])
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(SoakBenchOptions, argv, prog=PROG, description=__doc__)

    import ray  # lazy: heavy (ray), after parsing so --help is fast

    from learner.train import Run, train  # lazy: start-up time of --help (tensorboard, the actors)

    rng = np.random.default_rng(args.seed)
    injected: collections.Counter[str] = collections.Counter()
    last_fault_iteration = [0]
    state: dict = {}
    deadline = time.monotonic() + 60 * args.minutes

    def garbage(endpoint: str, router: bool, keys) -> None:
        """Random bytes from an insider (the run's actor keys: the codec refuses them) or an
        outsider (no keys: the CURVE handshake refuses it)."""
        sock = zmq.Context.instance().socket(zmq.DEALER if router else zmq.PUSH)
        curve_keys.make_client(sock, keys, curve_keys.ACTOR)
        sock.setsockopt(zmq.LINGER, 500)
        sock.connect(endpoint)
        junk = [bytes(rng.integers(0, 256, size=int(rng.integers(1, 200)), dtype=np.uint8))]
        sock.send_multipart([b"", *junk] if router else junk)
        if router:
            sock.poll(2000)
        sock.close()

    def hook(run: Run, metrics: dict) -> None:
        state["run"] = run
        if time.monotonic() > deadline:
            run.stop.request()
            return
        if rng.random() > args.fault_rate:
            return
        kind = str(rng.choice(["kill_actor", "stall_actor", "garbage_learner", "garbage_sampler", "sampler_outage"]))
        handle = run.pool.handles[int(rng.integers(len(run.pool.handles)))]
        try:
            if kind == "kill_actor":
                os.kill(ray.get(handle.stats.remote(), timeout=10)["pid"], signal.SIGKILL)
            elif kind == "stall_actor":
                handle.stall.remote(float(rng.uniform(2, 12)))
            elif kind in ("garbage_learner", "garbage_sampler"):
                keys = run.keys.for_actors() if run.keys is not None and rng.random() < 0.5 else None
                if kind == "garbage_learner":
                    garbage(run.transport.endpoints["unrolls"], router=False, keys=keys)
                    garbage(run.transport.endpoints["weights_router"], router=True, keys=keys)
                else:
                    garbage(run.sampler.endpoint, router=True, keys=keys)
            else:
                ray.kill(run.sampler.ray_handle, no_restart=False)
        except (ray.exceptions.RayError, OSError) as exc:  # the target was already down: not injected
            print(f"[soak] {kind} not injected: {exc}")
            return
        injected[kind] += 1
        last_fault_iteration[0] = run.learner.iteration
        print(f"[soak] iteration {run.learner.iteration}: injected {kind}", flush=True)

    cluster = start(rollout_per_worker=1, cpus_per_worker=1)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            base = PRESETS[args.preset][1]
            cfg = dataclasses.replace(
                base, name="soak", runs_dir=tmp, mode="cluster", ray_address=cluster.address, resume="never",
                total_env_steps=10**12, checkpoint_every=5, stall_timeout_s=5.0, quiet=True,
                actors=dataclasses.replace(base.actors, num_actors=2, sampler_timeout_s=0.5, sampler_retries=1),
            )
            t0 = time.monotonic()
            train(cfg, on_iteration=hook)
            run = state["run"]
            wall = time.monotonic() - t0
            t = run.transport
            sent = _ledger(run.run_dir)
            in_flight = sum(total - 1 - t.last_seq.get(a, -1) for a, total in sent.items())
            received = sum(t.received.values())
            gaps = t.counters["seq_gap_unrolls"]
            uncounted_wire = sum(sent.values()) - received - gaps - in_flight
            uncounted_learner = received - t.counters["unrolls_trained"] - t.counters["stale_unrolls"] - t.counters["unused_at_stop"]
            survived = sum(injected.values()) if run.learner.iteration > last_fault_iteration[0] else sum(injected.values()) - 1
            print(f"\nsoak: {wall / 60:.1f} min, {run.learner.iteration} iterations, {run.learner.env_steps:,d} env steps")
            print(f"faults injected   {sum(injected.values()):6d}  {dict(injected)}")
            print(f"faults survived   {survived:6d}  (training iterated after the fault)")
            rejected = {k: v for k, v in t.counters.items() if k.startswith("rejected/")}
            print(f"messages rejected {sum(rejected.values()):6d}  {rejected}")
            print(f"unrolls numbered  {sum(sent.values()):6d}  received {received}, trained {t.counters['unrolls_trained']}")
            print(f"unrolls lost, counted: {gaps + t.counters['stale_unrolls'] + t.counters['unused_at_stop'] + in_flight} "
                  f"(gaps {gaps}, stale {t.counters['stale_unrolls']}, unused at stop {t.counters['unused_at_stop']}, "
                  f"in flight at stop {in_flight})")
            print(f"unrolls lost, uncounted: {uncounted_wire + uncounted_learner}")
            return 0 if uncounted_wire + uncounted_learner == 0 else 1
    finally:
        cluster.shutdown()
