"""Nothing lost uncounted (issue 54, item 4), with real processes and sockets on 127.0.0.1: a
message over the unroll socket's size limit is counted, a killed and resumed learner continues
every counter family and counts the iterations, env steps and value pairs the kill cost, one
actor kill counts one restart, and a killed sampler comes back with its own saved state."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from actors.config import ActorConfig
from common import wire
from learner import checkpoint
from learner.presets import PRESETS
from learner.sampler_handle import pairs_taken_of
from learner.train import Run, train
from learner.transport import LearnerTransport
from tests.learner.actor_restart import restarted_pid

ROOT = Path(__file__).resolve().parents[2]


def test_a_message_over_the_size_limit_is_counted_not_silently_dropped():
    t = LearnerTransport("127.0.0.1", 3, 2, 1, unroll_length=2, envs_per_actor=1, num_actors=1,
                         max_msg_bytes=1 << 20)
    push = zmq.Context.instance().socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    push.connect(t.endpoints["unrolls"])
    try:
        beat = [bytes(f) for f in wire.encode(wire.HeartbeatMsg(actor_id=0, seq=0, env_steps=0))]
        push.send_multipart(beat)
        push.send(b"\0" * (2 << 20))  # libzmq drops the connection: the message never arrives
        push.send_multipart(beat)  # the peer reconnects and goes on
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not (t.counters["disconnects"] and t.counters["heartbeats"] >= 2):
            t.receive(50, 0, 0)
    finally:
        push.close(linger=0)
        t.close()
    assert t.counters["disconnects"] == 1, dict(t.counters)
    assert t.counters["heartbeats"] == 2  # what came before and after it was read


def _serial_args(runs: Path) -> list[str]:
    return [sys.executable, "-m", "learner.main", "--preset", "reach-tiny", "--mode", "serial", "--runs-dir", str(runs),
            "--total-env-steps", "1000000000", "--checkpoint-every", "4", "--stall-timeout-s", "0.01"]


def test_a_killed_learner_resumes_every_counter_and_counts_what_it_lost(tmp_path):
    """`--stall-timeout-s 0.01`: every PPO update is longer, so the health counters move for real."""
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    env["PYTHONUNBUFFERED"] = "1"
    proc = subprocess.Popen(_serial_args(tmp_path), cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line or line.startswith("iter     6"):  # progress.json says 5 by now (or 6)
            break
    proc.kill()  # SIGKILL: no handler, no checkpoint after iteration 4 (the next is at 8)
    proc.wait(timeout=30)
    run = tmp_path / "reach-tiny"
    reached = json.loads((run / "progress.json").read_text())
    _, saved = checkpoint.load_latest(run / "ckpt")
    assert saved["iteration"] == 4 and reached["iteration"] >= 5, reached
    assert saved["faults"]["health"]["stalls"] > 0

    stop_at = reached["iteration"] + 1
    resumed = subprocess.run([*_serial_args(tmp_path), "--max-iterations", str(stop_at)], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    out = resumed.stdout
    lost_iterations = reached["iteration"] - 4
    lost_steps = reached["env_steps"] - saved["env_steps"]
    assert f"{lost_iterations} iteration(s), {lost_steps:,d} env steps lost" in out, out
    _, final = checkpoint.load_latest(run / "ckpt")
    assert final["iteration"] == stop_at
    faults = final["faults"]
    assert faults["run"] == {"resumes": 1, "lost_iterations": lost_iterations, "lost_env_steps": lost_steps}
    for family in ("health", "pool", "sampler"):
        for name, value in saved["faults"][family].items():
            assert faults[family][name] >= value, (family, name)
    assert faults["health"]["stalls"] > saved["faults"]["health"]["stalls"]
    for name, value in saved["transport"]["counters"].items():
        assert final["transport"]["counters"][name] >= value, name
    # The unrolls the killed session took after its checkpoint: its lost iterations' worth (8 of
    # 128 steps each per iteration), and at most the part of an iteration it had begun, 8 more.
    per_unroll = 32 * 4
    at_resume = final["transport"]["counters"].get("lost/unrolls_at_resume", 0)
    assert lost_steps // per_unroll <= at_resume <= lost_steps // per_unroll + 8, at_resume
    assert final["transport"]["counters"].get("seq_gap_unrolls", 0) == saved["transport"]["counters"].get("seq_gap_unrolls", 0)
    assert final["transport"]["bytes_received"] > saved["transport"]["bytes_received"]
    # Every unroll received was trained on, dropped as stale, or left unused: at this stop, or by
    # the killed session (received before its checkpoint, waiting for the next batch).
    c = final["transport"]["counters"]
    assert c.get("unused_at_resume", 0) == saved["transport"]["pending_unrolls"]
    assert c["unrolls_received"] == (c["unrolls_trained"] + c.get("stale_unrolls", 0) + c.get("unused_at_stop", 0)
                                     + c.get("unused_at_resume", 0)), c
    assert final["transport"]["pending_unrolls"] == 0  # a clean stop counted them as unused_at_stop
    # The value pairs the sampler had taken after the checkpoint and no longer holds.
    came_back = int(re.search(r"sampler (?:kept its own state file|restored from the checkpoint) \((\d+) pairs", out).group(1))
    assert came_back >= pairs_taken_of(checkpoint.from_checkpointable(saved["sampler"]))
    assert faults["sampler"]["pairs_lost"] == max(0, int(reached["sampler_pairs_taken"]) - came_back)


def _local_cfg(tmp_path: Path, **overrides):
    base = PRESETS["reach-tiny"][1]
    return dataclasses.replace(
        base, runs_dir=str(tmp_path), quiet=True, mode="local", total_env_steps=10**9, checkpoint_every=1000,
        max_iterations=80,
        actors=ActorConfig(num_actors=2, envs_per_actor=4, unroll_length=32, draw_batch=4,
                           sampler_timeout_s=0.5, sampler_retries=1),
        **overrides)


@pytest.mark.usefixtures("one_thread")
def test_one_actor_kill_counts_one_restart(tmp_path):
    import ray

    seen: dict = {}

    def hook(run: Run, metrics: dict) -> None:
        if run.learner.iteration == 2:
            seen["pid"] = ray.get(run.pool.handles[0].stats.remote(), timeout=30)["pid"]
            os.kill(seen["pid"], signal.SIGKILL)
        if "pid" in seen and "back_at" not in seen:
            if restarted_pid(run.pool.handles[0], seen["pid"]) is not None:
                seen["back_at"] = run.transport.received[0]
        # The new process has been sending for a while: every failed resubmission is behind us.
        if "back_at" in seen and run.transport.received[0] >= seen["back_at"] + 4:
            seen["restarts"] = metrics["faults/actor_restarts"]
            run.stop.event.set()

    assert train(_local_cfg(tmp_path), on_iteration=hook) == 0
    assert "restarts" in seen, f"the killed actor never came back: {seen}"
    assert seen["restarts"] == 1
    _, state = checkpoint.load_latest(tmp_path / "reach-tiny" / "ckpt")
    assert state["faults"]["pool"]["actor_restarts"] == 1


@pytest.mark.usefixtures("one_thread")
def test_a_killed_sampler_comes_back_with_its_own_state_and_lost_pairs_are_counted(tmp_path):
    import ray

    seen: dict = {}

    def hook(run: Run, metrics: dict) -> None:
        it = run.learner.iteration
        if it >= 4 and "killed_at" not in seen and metrics.get("sampler/state/saves", 0) >= 1:
            seen["before"] = dict(metrics)
            seen["killed_at"] = it
            ray.kill(run.sampler.ray_handle, no_restart=False)  # like SIGKILL: no save at stop; Ray restarts it
        if "killed_at" in seen and metrics.get("faults/sampler_restarts", 0) >= 1:
            seen["after"] = dict(metrics)
            seen["delivered"], seen["lost"] = run.sampler.pairs_delivered, run.sampler.pairs_lost
            run.stop.event.set()

    sampler = dataclasses.replace(PRESETS["reach-tiny"][1].sampler, state_every_s=0.5)
    assert train(_local_cfg(tmp_path, sampler=sampler), on_iteration=hook) == 0
    assert "after" in seen, f"the killed sampler never answered again: {seen.get('killed_at')}"
    before, after = seen["before"], seen["after"]
    assert after["sampler/state/restored"] == 1  # it began from its own file, not empty
    assert after["faults/sampler_restores"] == 1
    assert after["sampler/vm/pairs_taken"] > 0
    # Every pair the learner delivered is held by the sampler or counted lost.
    assert seen["delivered"] == after["sampler/vm/pairs_taken"] + seen["lost"]
    assert seen["lost"] <= before["sampler/vm/pairs_taken"]
    assert after["faults/value_pairs_lost"] == seen["lost"]
    assert (tmp_path / "reach-tiny" / "sampler" / "sampler-state.npz").is_file()
    np.testing.assert_equal(after["faults/value_pairs_queued"], 0)
