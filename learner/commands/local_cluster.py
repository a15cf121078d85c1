"""Start the local two-worker test cluster: a Ray head and two worker nodes, all on this
machine (loopback), tagged with the custom resources the learner places by: the head hosts the
sampler and up to `--learner-slots` data-parallel learner replicas beside the training process
(`--learner.replicas`), each worker `--rollout-per-worker` rollout actors.

    morphmimic local-cluster                  # prints the address, runs until Ctrl-C
    RAY_ADDRESS=<printed address> morphmimic train --mode cluster

Ctrl-C (or SIGTERM) stops all three nodes.
"""

from __future__ import annotations

import signal
import threading
from dataclasses import dataclass
from typing import ClassVar

from common.config_limits import Limit, at_least, check_limits, validated
from learner.cli_options import parse_options
from learner.cluster import start_test_cluster as start


@validated
@dataclass
class LocalClusterOptions:
    rollout_per_worker: int = 1
    """Rollout actors each worker node may host."""
    cpus_per_worker: int = 1
    """CPUs each worker node advertises."""
    learner_slots: int = 1
    """Data-parallel learner replicas the head may host besides the training process."""

    LIMITS: ClassVar[dict[str, Limit]] = {"rollout_per_worker": at_least(1), "cpus_per_worker": at_least(1),
                                          "learner_slots": at_least(0)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(LocalClusterOptions, argv, prog="morphmimic local-cluster", description=__doc__)
    cluster = start(args.rollout_per_worker, args.cpus_per_worker, args.learner_slots)
    actors = 2 * args.rollout_per_worker
    print(f"two-worker test cluster up: head + 2 workers at {cluster.address}")
    print("point the learner at it:")
    print(f"  RAY_ADDRESS={cluster.address} morphmimic train --mode cluster --actors.num-actors {actors}")
    print("stop it: Ctrl-C here (or kill -TERM this process)", flush=True)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    done.wait()
    cluster.shutdown()
    print("cluster stopped")
    return 0
