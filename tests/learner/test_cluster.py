"""Cluster mode on the local two-worker test cluster (a head and two worker nodes on this
machine, as `morphmimic local-cluster` starts them): the learner attaches, places one rollout
actor per worker node by custom resource, and trains."""

from __future__ import annotations

import dataclasses
import json

import pytest

from actors.config import ActorConfig
from learner import checkpoint
from learner.presets import PRESETS
from learner.train import train

pytestmark = pytest.mark.cluster


@pytest.fixture(scope="module")
def two_worker_cluster():
    from learner.cluster import start_test_cluster as start

    cluster = start(rollout_per_worker=1, cpus_per_worker=1)
    yield cluster
    cluster.shutdown()


def test_actors_run_on_both_workers_and_iterations_complete(two_worker_cluster, tmp_path):
    cluster = two_worker_cluster
    worker_ids = {node.node_id for node in cluster.worker_nodes}
    cfg = dataclasses.replace(
        PRESETS["reach-tiny"][1], runs_dir=str(tmp_path), quiet=True, mode="cluster",
        ray_address=cluster.address, max_iterations=60, total_env_steps=10**6,
        actors=ActorConfig(num_actors=2, envs_per_actor=4, unroll_length=32),
    )
    done_at = []

    def stop_once_both_actors_delivered(run, metrics) -> None:
        # NOTE: on a loaded machine one actor may start seconds after the other, which alone can
        # fill the first iterations: train until both have delivered (at least 3 iterations,
        # bounded by max_iterations), then stop the way Ctrl-C does.
        if run.learner.iteration >= 3 and len(run.transport.received) == 2 and not done_at:
            done_at.append(run.learner.iteration)
            run.stop.request()

    assert train(cfg, on_iteration=stop_once_both_actors_delivered) == 0
    assert done_at, "one rollout actor delivered nothing in 60 iterations"
    run = tmp_path / "reach-tiny"
    log = (run / "log.txt").read_text()
    assert "mode cluster" in log
    assert checkpoint.load_latest(run / "ckpt")[1]["iteration"] == done_at[0]
    actors = json.loads((run / "actors.json").read_text())
    assert {a["node_id"] for a in actors} == worker_ids, (actors, worker_ids)
    assert all(a["env_steps"] > 0 for a in actors)


def test_cluster_mode_without_a_cluster_says_so(tmp_path, monkeypatch):
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    from learner import cluster

    monkeypatch.setattr(cluster, "find_running_cluster", lambda explicit="": None)
    with pytest.raises(RuntimeError, match="no running Ray cluster found"):
        cluster.connect("cluster", "", 1, 1.0)


def test_two_data_parallel_learners_stay_equal_and_learn_reach(two_worker_cluster, tmp_path):
    """`--learner.replicas 2` on the two-worker cluster: the training process and one replica
    actor (on the head, by the `morphmimic_learner` resource) in a gloo group on 127.0.0.1.
    Their parameters must agree to 1e-6 after every update checked, and the run must learn
    `reach` on the serial learning test's budget and threshold (untrained: about 1-3)."""
    from common.policy import GaussianPolicy
    from learner.config import LearnerConfig
    from learner.replicas import flat_parameters
    from tests.learner.test_training import _mean_return

    cluster = two_worker_cluster
    cfg = dataclasses.replace(
        PRESETS["reach"][1], name="dp", runs_dir=str(tmp_path), quiet=True, mode="cluster", ray_address=cluster.address,
        total_env_steps=16 * 4096, checkpoint_every=100, learner=LearnerConfig(replicas=2, threads=1),
        actors=dataclasses.replace(PRESETS["reach"][1].actors, num_actors=2),
    )
    gaps: list[float] = []

    def compare_replicas(run, metrics) -> None:
        if run.learner.iteration % 4 == 1:
            mine = flat_parameters(run.learner)
            gaps.extend(float(abs(other - mine).max()) for other in run.learner.replicas.parameters())

    assert train(cfg, on_iteration=compare_replicas) == 0
    assert len(gaps) >= 4 and max(gaps) <= 1e-6, gaps
    assert f"2 data-parallel learners on cpu (gloo, rendezvous file://{tmp_path.resolve()}/dp/rendezvous-" in (
        tmp_path / "dp" / "log.txt").read_text()
    state = checkpoint.load_latest(tmp_path / "dp" / "ckpt")[1]
    assert state["env_steps"] >= cfg.total_env_steps
    trained = GaussianPolicy(12, 2, cfg.policy)
    trained.load_state_dict(state["policy"])
    assert _mean_return(trained, cfg) > 15.0
