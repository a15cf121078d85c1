"""Start the local two-worker test cluster: a Ray head and two worker nodes, all on this
machine (loopback), tagged with the custom resources the learner places by: the head hosts the
sampler and up to `--learner-slots` data-parallel learner replicas beside the training process
(`--learner.replicas`), each worker `--rollout-per-worker` rollout actors.

    python deploy/local_cluster.py            # prints the address, runs until Ctrl-C
    RAY_ADDRESS=<printed address> python -m learner.main --mode cluster

Ctrl-C (or SIGTERM) stops all three nodes.
"""

from __future__ import annotations

import argparse
import signal
import threading

from learner.cluster import start_test_cluster as start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rollout-per-worker", type=int, default=1, help="rollout actors each worker node may host")
    parser.add_argument("--cpus-per-worker", type=int, default=1, help="CPUs each worker node advertises")
    parser.add_argument("--learner-slots", type=int, default=1,
                        help="data-parallel learner replicas the head may host besides the training process")
    args = parser.parse_args()
    if args.rollout_per_worker < 1 or args.cpus_per_worker < 1 or args.learner_slots < 0:
        parser.error("--rollout-per-worker and --cpus-per-worker must be at least 1, --learner-slots at least 0")
    cluster = start(args.rollout_per_worker, args.cpus_per_worker, args.learner_slots)
    actors = 2 * args.rollout_per_worker
    print(f"two-worker test cluster up: head + 2 workers at {cluster.address}")
    print("point the learner at it:")
    print(f"  RAY_ADDRESS={cluster.address} python -m learner.main --mode cluster --actors.num-actors {actors}")
    print("stop it: Ctrl-C here (or kill -TERM this process)", flush=True)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    done.wait()
    cluster.shutdown()
    print("cluster stopped")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
