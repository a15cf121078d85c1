"""Fault injection on the local two-worker test cluster: an actor process killed, a worker node
lost and returned, a stalled actor, a sampler outage, hostile bytes on every socket, and a
learner SIGKILLed and resumed. Each test asserts that iterations keep increasing and that every
lost or refused message shows up in a counter."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import torch
import zmq

from actors.config import ActorConfig
from common import sockets, wire
from learner import checkpoint
from learner.presets import PRESETS
from learner.train import Run, train
from tests.learner.actor_restart import restarted_pid

pytestmark = pytest.mark.cluster
ROOT = Path(__file__).resolve().parents[2]


def _cfg(tmp_path: Path, address: str, **overrides):
    base = dataclasses.replace(
        PRESETS["reach-tiny"][1], runs_dir=str(tmp_path), quiet=True, mode="cluster", ray_address=address,
        total_env_steps=10**9, checkpoint_every=1,
        actors=ActorConfig(num_actors=2, envs_per_actor=4, unroll_length=32, draw_batch=4,
                           sampler_timeout_s=0.5, sampler_retries=1),
    )
    return dataclasses.replace(base, **overrides)


def _ledger_total(run_dir: Path) -> dict[int, int]:
    """Unrolls each actor numbered (sent or about to be sent), from the durable ledger."""
    return {int(p.stem.split("-")[1]): int(p.read_text().strip("\0 \n")) + 1 for p in (run_dir / "ledger").glob("actor-*.seq")}


def _assert_every_unroll_accounted(run: Run) -> None:
    """Ground truth (the ledger) = received + counted gaps, with nothing left "in flight": the
    drain at stop read until every actor's final heartbeat, whose seq covers its last unroll."""
    sent = _ledger_total(run.run_dir)
    t = run.transport
    assert t.finals.keys() == sent.keys(), (t.finals, sent)
    for actor_id, total in sent.items():
        assert t.last_seq.get(actor_id, -1) == total - 1 == t.finals[actor_id]
        assert t.received[actor_id] <= total
    received = sum(t.received.values())
    assert sum(sent.values()) == received + t.counters["seq_gap_unrolls"]


@pytest.fixture
def cluster():
    from learner.cluster import start_test_cluster as start

    c = start(rollout_per_worker=1, cpus_per_worker=1)
    yield c
    c.shutdown()


def test_killed_actor_is_restarted_and_in_flight_losses_are_counted(cluster, tmp_path):
    seen: dict = {}

    def hook(run: Run, metrics: dict) -> None:
        it = run.learner.iteration
        import ray

        if it == 2:
            seen["killed_pid"] = ray.get(run.pool.handles[0].stats.remote())["pid"]
            os.kill(seen["killed_pid"], signal.SIGKILL)
        # NOTE: recovered = the restarted process (another pid) delivered an unroll of its own.
        # "Reporting" alone also counts the killed actor within its stall timeout, and unrolls
        # the killed process had queued can still arrive; a stop sent while the new process had
        # not started its loop left no final heartbeat to account its tail.
        if "killed_pid" in seen and "back_at_received" not in seen:
            if restarted_pid(run.pool.handles[0], seen["killed_pid"]) is not None:
                seen["back_at_received"] = run.transport.received[0]
        if (metrics["faults/actor_restarts"] >= 1 and it >= 6 and "back_at_received" in seen
                and run.transport.received[0] > seen["back_at_received"]):
            seen["recovered_at"] = it
            run.stop.event.set()
        seen["run"] = run

    assert train(_cfg(tmp_path, cluster.address, max_iterations=40), on_iteration=hook) == 0
    run = seen["run"]
    assert "recovered_at" in seen, "the killed actor never came back"
    assert run.learner.iteration >= 6
    _assert_every_unroll_accounted(run)


def test_lost_node_leaves_training_elastic_and_actors_return_with_capacity(cluster, tmp_path):
    alive: list[float] = []
    events: dict = {}

    def hook(run: Run, metrics: dict) -> None:
        it = run.learner.iteration
        alive.append(metrics["health/actors_reporting"])
        if it == 2:
            import ray

            node_id = ray.get(run.pool.handles[1].stats.remote())["node_id"]
            node = next(n for n in cluster.worker_nodes if n.node_id == node_id)
            events["removed"] = it
            cluster.remove_node(node)
        if "removed" in events and "added" not in events and metrics["health/actors_reporting"] == 1:
            events["degraded_at"] = it
            events["added"] = it
            cluster.add_node(num_cpus=1, resources={"morphmimic_rollout": 1})
        if "added" in events and metrics["health/actors_reporting"] == 2 and it > events["added"]:
            events["back_at"] = it
            run.stop.event.set()

    cfg = _cfg(tmp_path, cluster.address, max_iterations=60, stall_timeout_s=4.0)
    assert train(cfg, on_iteration=hook) == 0
    assert "degraded_at" in events, f"never saw training continue with one actor: {alive}"
    assert "back_at" in events, f"actors did not come back with capacity: {alive}"


def test_stalled_actor_is_detected_excluded_and_readmitted(cluster, tmp_path):
    seen: dict = {}

    def hook(run: Run, metrics: dict) -> None:
        if run.learner.iteration == 2:
            run.pool.handles[0].stall.remote(8.0)
        if metrics["health/stalls"] >= 1:
            seen.setdefault("stalled_at", run.learner.iteration)
        if metrics["health/readmissions"] >= 1:
            seen["readmitted_at"] = run.learner.iteration
            run.stop.event.set()

    assert train(_cfg(tmp_path, cluster.address, max_iterations=80, stall_timeout_s=3.0), on_iteration=hook) == 0
    assert "stalled_at" in seen and "readmitted_at" in seen, seen
    assert seen["readmitted_at"] > seen["stalled_at"]


def test_sampler_outage_degrades_then_recovers_with_its_state(cluster, tmp_path):
    import ray

    seen: dict = {}

    def hook(run: Run, metrics: dict) -> None:
        it = run.learner.iteration
        handle = run.sampler.ray_handle
        if it == 3:
            ray.get(handle.stop.remote())  # the service goes silent: clients time out
            seen["down_at"] = it
        if "down_at" in seen and "restarted_at" not in seen and metrics["faults/actor_sampler_outages"] > 0:
            # Checkpoints written while it is silent keep the previous one's sampler state.
            latest = checkpoint.list_checkpoints(run.run_dir / "ckpt")[-1]
            seen["ckpt_has_sampler"] = "sampler" in torch.load(latest / checkpoint.FILE, weights_only=True)
            ray.kill(handle, no_restart=False)  # Ray brings it back, empty, on a new port
            seen["restarted_at"] = it
        if metrics["faults/sampler_restores"] >= 1 and "restored_at" not in seen:
            seen["restored_at"] = it
            seen["restored_pairs"] = run.sampler.saved_state["meta"]["vm"]["pairs_seen"]
        if "restored_at" in seen and "sampler/vm/pairs_seen" in metrics:
            # The first tick the restored service answers (the one right after the restore may
            # time out under load: its first MCMC refill runs in it).
            seen["vm_pairs"] = metrics["sampler/vm/pairs_seen"]
            run.stop.event.set()

    assert train(_cfg(tmp_path, cluster.address, max_iterations=60), on_iteration=hook) == 0
    assert "restarted_at" in seen, f"actors never counted the outage: {seen}"
    assert "restored_at" in seen, f"the restarted sampler never got its state back: {seen}"
    assert "vm_pairs" in seen, f"the restored sampler never answered a tick: {seen}"
    # The restored marginal value kept what it had learned: it counts at least the pairs of
    # the checkpoint it was given (a live count never decreases; an empty one starts at 0).
    assert seen["vm_pairs"] >= seen["restored_pairs"] > 0, seen
    assert seen["ckpt_has_sampler"]
    assert "sampler state unavailable" in next(tmp_path.glob("*/log.txt")).read_text()


def _hostile_frames(obs_dim: int = 12, T: int = 32, N: int = 4) -> list[tuple[str, list[bytes]]]:
    """Unrolls shaped like the run's (reach, T x N of `_cfg`), each wrong in one way."""
    good = wire.UnrollMsg(
        actor_id=0, seq=0, policy_version=0, obs=np.zeros((T, N, obs_dim), np.float32),
        next_obs=np.zeros((T, N, obs_dim), np.float32), actions=np.zeros((T, N, 2), np.float32),
        logp=np.zeros((T, N), np.float32), rewards=np.zeros((T, N), np.float32),
        terminated=np.zeros((T, N), bool), truncated=np.zeros((T, N), bool), params=np.zeros((T, N, 2), np.float32),
    )
    frames = [bytes(f) for f in wire.encode(good)]
    nan = [bytes(f) for f in wire.encode(dataclasses.replace(good, rewards=np.full((T, N), np.nan, np.float32)))]
    wrong_shape = [bytes(f) for f in wire.encode(dataclasses.replace(good, obs=np.zeros((T, N, obs_dim + 1), np.float32)))]
    header = msgpack.unpackb(frames[0])
    header["v"] = 42
    phantom = [bytes(f) for f in wire.encode(wire.HeartbeatMsg(actor_id=99, seq=0, env_steps=0))]
    return [
        ("malformed", [b"\x00garbage\xff"]),
        ("malformed", frames[:-3]),  # truncated multipart
        ("version", [msgpack.packb(header), *frames[1:]]),
        ("nonfinite", nan),
        ("bad_shape", wrong_shape),
        ("unknown_actor", phantom),
    ]


def test_hostile_bytes_are_rejected_counted_and_training_continues(cluster, tmp_path):
    """An insider (a peer holding the run's actor keys) sends malformed messages: the codec
    refuses and counts each by kind. An outsider without keys is refused by the CURVE handshake
    on every socket, and counted."""
    seen: dict = {}

    def hook(run: Run, metrics: dict) -> None:
        if run.learner.iteration == 2:
            ctx = zmq.Context.instance()
            insider = run.keys.for_actors()
            push = sockets.connect_unroll_push(run.transport.endpoints["unrolls"], insider)
            for _, frames in _hostile_frames():
                push.send_multipart(frames)
            push.close(linger=1000)
            for kind, endpoint in ((zmq.PUSH, run.transport.endpoints["unrolls"]),
                                   (zmq.DEALER, run.transport.endpoints["weights_router"]),
                                   (zmq.DEALER, run.sampler.endpoint)):
                outsider = ctx.socket(kind)
                outsider.setsockopt(zmq.LINGER, 0)
                outsider.connect(endpoint)
                seen.setdefault("outsiders", []).append(outsider)
            # NOTE: this hook runs on the learner's own thread, so replies are read later, after
            # the learner has been back in its receive loop.
            seen["dealers"] = []
            for endpoint in (run.transport.endpoints["weights_router"], run.sampler.endpoint):
                dealer = sockets.connect_dealer(endpoint, insider)
                dealer.send_multipart([b"", b"\xc1garbage"])
                dealer.send_multipart([b"", msgpack.packb({"p": wire.PROTOCOL, "k": "tick", "v": 7, "f": {}, "a": []})])
                seen["dealers"].append(dealer)
        if run.learner.iteration == 6:
            for outsider in seen.pop("outsiders"):
                outsider.close(linger=0)
            seen["replies"] = []
            for dealer in seen.pop("dealers"):
                for _ in range(2):
                    if dealer.poll(5000):
                        seen["replies"].append(wire.decode(dealer.recv_multipart()[1:]))
                dealer.close()
            seen["counters"] = dict(run.transport.counters)
            seen["run"] = run
            seen["weights_rejected"] = dict(run.transport.snapshots.rejected)
            seen["sampler_stats"] = run.sampler.client.stats()

    assert train(_cfg(tmp_path, cluster.address, max_iterations=6), on_iteration=hook) == 0
    c = seen["counters"]
    for kind in ("malformed", "version", "nonfinite", "bad_shape", "unknown_actor"):
        assert c[f"rejected/{kind}"] >= 1, (kind, c)
    assert 99 not in seen["run"].transport.last_seen  # no phantom actor in the health counters
    assert len(seen["replies"]) == 4 and all(isinstance(r, wire.ErrorMsg) for r in seen["replies"])
    assert sum(v for k, v in seen["weights_rejected"].items() if not k.startswith("auth_")) == 2
    assert seen["sampler_stats"]["requests/rejected"] >= 2
    # The outsiders: refused by the handshake on the unroll socket, the weights ROUTER, the sampler.
    assert sum(v for k, v in c.items() if k.startswith("rejected/auth_")) >= 1, c
    assert sum(v for k, v in seen["weights_rejected"].items() if k.startswith("auth_")) >= 1, seen["weights_rejected"]
    assert sum(v for k, v in seen["sampler_stats"].items() if k.startswith("requests/rejected/auth_")) >= 1


def test_learner_sigkill_then_resume_continues_from_last_checkpoint(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    args = [sys.executable, "-m", "learner.main", "--preset", "reach-tiny", "--mode", "local",
            "--runs-dir", str(tmp_path), "--total-env-steps", "1000000000", "--checkpoint-every", "1"]
    proc = subprocess.Popen(args, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        if proc.stdout.readline().startswith("iter     3"):
            break
    proc.kill()  # SIGKILL: no handler runs, no final checkpoint
    proc.wait(timeout=30)
    ckpt = tmp_path / "reach-tiny" / "ckpt"
    before = checkpoint.load_latest(ckpt)[1]["iteration"]
    assert before >= 2
    resumed = subprocess.run([*args, "--max-iterations", str(before + 2)], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert f"at iteration {before}" in resumed.stdout
    assert checkpoint.load_latest(ckpt)[1]["iteration"] == before + 2


def test_an_unexpected_exception_in_the_loop_writes_a_checkpoint_and_exits_nonzero(tmp_path):
    """The PPO update raises on iteration 3 of a serial run that checkpoints only every 100
    iterations: the two finished iterations are saved before the process exits with an error."""
    script = (
        "import sys\n"
        "from learner import ppo\n"
        "from learner.main import main\n"
        "real, calls = ppo.PPO.update, []\n"
        "def update(self, *a, **kw):\n"
        "    calls.append(1)\n"
        "    if len(calls) == 3:\n"
        "        raise RuntimeError('injected failure in the PPO update')\n"
        "    return real(self, *a, **kw)\n"
        "ppo.PPO.update = update\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    proc = subprocess.run([sys.executable, "-c", script, "--preset", "reach-tiny", "--mode", "serial",
                           "--runs-dir", str(tmp_path), "--total-env-steps", "1000000", "--checkpoint-every", "100"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode != 0, proc.stdout + proc.stderr
    assert "injected failure in the PPO update" in proc.stderr
    run = tmp_path / "reach-tiny"
    _, state = checkpoint.load_latest(run / "ckpt")
    assert state["iteration"] == 2 and "transport" in state and "sampler" in state
    assert "RuntimeError in the training loop at iteration 2" in (run / "log.txt").read_text()
