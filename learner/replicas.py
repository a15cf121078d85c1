"""`--learner.replicas N`: N learner processes share each PPO update (data parallel).

The training process is rank 0: it still receives every unroll, publishes the weights, talks to
the sampler and writes the checkpoints. Ranks 1..N-1 are Ray actors (`LearnerReplica`), placed by
the `morphmimic_learner` resource where a node advertises it, and given one GPU each when the
learner runs on cuda. At start each receives rank 0's whole learner state (networks, optimizer,
minibatch generator) and joins a torch.distributed group (gloo on CPU, nccl on GPU) that meets
at a file in the run directory when every node is on this machine, else at a TCP port on rank
0's host (`learner.data_parallel.rendezvous`). Every iteration rank 0 puts the batch into Ray's object store once,
every replica runs `Learner.apply_update` on it, and `learner.data_parallel.GradientSync` keeps
their steps equal. What goes between them per minibatch step is one all-reduce of the gradients.

A replica that dies makes the next all-reduce fail after `--learner.sync-timeout-s` (gloo); the
run then writes a checkpoint and exits, to be resumed (`--resume auto`). A checksum compared
after every update stops the run if the copies drift apart.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from learner import cluster, data_parallel
from learner.config import RunConfig
from learner.learner import Learner
from learner.ppo import Batch

log = logging.getLogger(__name__)


def flat_parameters(learner: Learner) -> np.ndarray:
    """Every trained tensor of the policy and value net, flattened (to compare replicas)."""
    tensors = [*learner.policy.state_dict().values(), *learner.value.state_dict().values()]
    return torch.cat([t.detach().reshape(-1).double().cpu() for t in tensors]).numpy()


class LearnerReplica:
    """Rank >= 1 of the data-parallel group: a Ray actor holding a copy of the learner."""

    def __init__(self, cfg_json: str, rank: int, world: int, init_method: str, state: dict[str, Any]):
        cfg = RunConfig.from_json(cfg_json)
        torch.set_num_threads(cfg.resolved_learner_threads)
        self.learner = Learner(cfg)
        self.learner.load_state_dict(state)
        self.rank, self.world, self.init_method = rank, world, init_method

    def join(self) -> int:
        data_parallel.join(self.init_method, self.rank, self.world, self.learner.device, self.learner.cfg.learner.sync_timeout_s)
        self.learner.sync = data_parallel.GradientSync(self.rank, self.world)
        return self.rank

    def update(self, batch: Batch, env_steps: int) -> dict[str, float]:
        return self.learner.apply_update(batch, env_steps)

    def parameters(self) -> np.ndarray:
        return flat_parameters(self.learner)

    def leave(self) -> None:
        data_parallel.leave()


def _join_watching_replicas(init_method: str, world: int, learner: Learner, joined: list, timeout_s: float) -> None:
    """Join the group as rank 0 while watching the replicas' own join calls, so that a replica
    that fails to start (its constructor raised, no node can host it) is reported at once with
    its own error, not as a rendezvous timeout `timeout_s` later."""
    import ray  # lazy: heavy (ray), only with more than one learner replica

    failure: list[BaseException] = []

    def join() -> None:
        try:
            data_parallel.join(init_method, 0, world, learner.device, timeout_s)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            failure.append(exc)

    thread = threading.Thread(target=join, name="rank0-join", daemon=True)
    thread.start()
    deadline = time.monotonic() + timeout_s
    while thread.is_alive():
        ready, _ = ray.wait(joined, num_returns=len(joined), timeout=0.5)
        for ref in ready:
            ray.get(ref)  # raises the replica's error
        if time.monotonic() > deadline:
            raise TimeoutError(f"learner replicas did not join within --learner.sync-timeout-s {timeout_s:g} s; "
                               f"is there a node with a free {cluster.LEARNER_RESOURCE} unit (and a GPU with cuda)?")
    if failure:
        raise failure[0]
    ray.get(joined, timeout=timeout_s)


class ReplicaGroup:
    """Rank 0's handle on the other replicas: starts them, runs their share of each update, stops them."""

    def __init__(self, handles: list, learner: Learner):
        self.handles, self.learner = handles, learner
        self.description = ""

    @classmethod
    def start(cls, cfg: RunConfig, ctx: cluster.RayContext | None, learner: Learner, host: str,
              run_dir: Path) -> ReplicaGroup | None:
        """Start replicas 1..N-1 and form the group with this process as rank 0 (None for one replica)."""
        world = cfg.learner.replicas
        if world == 1:
            return None
        import ray  # lazy: heavy (ray), only with more than one learner replica

        init_method = data_parallel.rendezvous(host, run_dir)
        options = cluster.actor_options(ctx, cluster.LEARNER_RESOURCE, 1.0, 0.0) if ctx is not None else {}
        if learner.device.type == "cuda":
            options["num_gpus"] = 1
        if data_parallel.on_one_machine(init_method):
            options["runtime_env"] = {"env_vars": data_parallel.LOOPBACK_ENV}
        state = ray.put(learner.state_dict())
        remote = ray.remote(LearnerReplica).options(max_restarts=0, **options)
        handles = [remote.remote(cfg.to_json(), rank, world, init_method, state) for rank in range(1, world)]
        joined = [h.join.remote() for h in handles]
        group = cls(handles, learner)
        try:
            _join_watching_replicas(init_method, world, learner, joined, cfg.learner.sync_timeout_s)
        except BaseException:
            group.stop()
            raise
        learner.sync = data_parallel.GradientSync(0, world)
        learner.replicas = group
        group.description = (f"{world} data-parallel learners on {learner.device.type} "
                             f"({data_parallel.backend(learner.device)}, rendezvous {init_method})")
        return group

    def start_update(self, batch: Batch, env_steps: int) -> list:
        import ray  # lazy: heavy (ray), only with more than one learner replica

        ref = ray.put(batch)
        return [h.update.remote(ref, env_steps) for h in self.handles]

    def finish_update(self, pending: list, timeout_s: float | None = None) -> None:
        """Wait for the replicas' share of the update; a replica's error is raised here."""
        import ray  # lazy: heavy (ray), only with more than one learner replica

        ray.get(pending, timeout=self.learner.cfg.learner.sync_timeout_s if timeout_s is None else timeout_s)

    def parameters(self) -> list[np.ndarray]:
        """Each replica's parameters, rank 1 first (for tests and checks)."""
        import ray  # lazy: heavy (ray), only with more than one learner replica

        return ray.get([h.parameters.remote() for h in self.handles])

    def stop(self) -> None:
        import ray  # lazy: heavy (ray), only with more than one learner replica

        data_parallel.leave()
        for h in self.handles:
            try:
                ray.kill(h)
            except Exception as exc:  # noqa: BLE001 - already gone
                log.warning("could not stop a learner replica: %s", exc)
        self.learner.sync = None
        self.learner.replicas = None
