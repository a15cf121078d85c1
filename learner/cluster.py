"""Ray lifecycle: decide which cluster to use (and say so), place the sampler and the rollout
actors by custom resources, and stop them. Ray never sits on the per-step path: data moves
over ZeroMQ; Ray starts, places, restarts and stops processes.

Custom resources (set on `ray start --resources=...`, see deploy/README.md):
    morphmimic_rollout  one unit per rollout actor a node may host
    morphmimic_sampler  the node that hosts the sampler service
    morphmimic_learner  one unit per data-parallel learner replica (`--learner.replicas`) a node may
                        host besides the training process itself
A cluster without them still works: actors are then spread over the nodes (SPREAD) and a
warning says so.

The private local instance (`--mode local`, or auto with no cluster) exposes nothing: every Ray
server in it (GCS, raylet, workers, the agents' metrics ports) listens on 127.0.0.1 only
(`loopback_only`), the dashboard is off, and nothing of it outlives the learner by more than a
few seconds (`learner/ray_reaper.py`), even when the learner is SIGKILLed.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import os
import socket
from dataclasses import dataclass, field
from typing import Any

from learner import ray_reaper

LOOPBACK = "127.0.0.1"
"""The node address of a private instance and of the test cluster: their servers bind it only."""

log = logging.getLogger(__name__)

ROLLOUT_RESOURCE = "morphmimic_rollout"
SAMPLER_RESOURCE = "morphmimic_sampler"
LEARNER_RESOURCE = "morphmimic_learner"


@dataclass(frozen=True)
class RayContext:
    kind: str
    """"cluster" (attached to a running cluster) or "local" (a private instance we started)."""
    address: str
    resources: dict[str, float]
    node_ips: tuple[str, ...]
    reaper: Any = field(default=None, compare=False, repr=False)
    """The local instance's watcher (`ray_reaper.Reaper`), closed by `shutdown`; None when attached."""


def _gcs_alive(address: str) -> bool:
    host, _, port = address.rpartition(":")
    try:
        with socket.create_connection((host, int(port)), timeout=1.0):
            return True
    except (OSError, ValueError):
        return False


def find_running_cluster(explicit: str = "") -> tuple[str, str] | None:
    """The cluster to attach to and how it was found, or None.

    Only an explicit address, RAY_ADDRESS, or the cluster that `ray start` on this machine
    recorded (and whose GCS still answers) count: never some other cluster that happens to run.
    """
    if explicit:
        return explicit, "--ray-address"
    if os.environ.get("RAY_ADDRESS"):
        return os.environ["RAY_ADDRESS"], "RAY_ADDRESS"
    try:
        # lazy: heavy (ray), only when looking for a cluster; a private API that may be absent
        from ray._private.utils import read_ray_address

        recorded = read_ray_address(None)
    except Exception:  # noqa: BLE001 - private API: absence means no cluster
        recorded = None
    if recorded and _gcs_alive(recorded):
        return recorded, "`ray start` on this machine"
    return None


def _use_token_auth_if_available() -> None:
    """Ray >= 2.5x starts `ray start` clusters with token authentication and keeps the token in
    ~/.ray/auth_token, but a driver attaching to them sends it only in token mode.

    NOTE: not for an explicit --ray-address: re-initializing Ray's config in a process that
    also hosts a `ray.cluster_utils.Cluster` (tests) cancels the first actor it creates."""
    if os.environ.get("RAY_AUTH_MODE"):
        return
    try:
        # lazy: heavy (ray), only when attaching to a cluster; absent in older Ray
        from ray._private.authentication.authentication_token_setup import maybe_enable_token_auth_if_token_available

        maybe_enable_token_auth_if_token_available(warn_if_disabled=False)
    except Exception:  # noqa: BLE001 - older Ray without token auth: nothing to do
        pass


def _token_auth_for_local_instance() -> None:
    """A private local instance uses token authentication (Ray >= 2.5x's default), with the mode
    set explicitly: left unset, Ray turns it on itself and says so in a WARNING on every run
    ("Token authentication is enabled ... Set RAY_AUTH_MODE=disabled to opt out"), a notice the
    user cannot act on. A mode the user set (RAY_AUTH_MODE) is left as it is, so is an older Ray.

    NOTE: the mode is read when Ray's config is initialized (at import); Ray's own default path
    sets it and re-initializes the config the same way, at the same moment of `ray.init`."""
    if os.environ.get("RAY_AUTH_MODE"):
        return
    try:
        from ray._raylet import Config  # lazy: heavy (ray), only when starting a private instance; absent in older Ray
    except ImportError:
        return
    os.environ["RAY_AUTH_MODE"] = "token"
    Config.initialize("")


@contextlib.contextmanager
def loopback_only():
    """While a private instance starts: Ray takes 127.0.0.1 as this node's address, and its
    servers then bind loopback only (Ray binds a gRPC server to 127.0.0.1 exactly when its node
    address is 127.0.0.1, else to all interfaces; its agents and metrics servers likewise).

    NOTE: Ray 2.60 offers no option for it: `ray.init(_node_ip_address="127.0.0.1")` is turned
    back into the machine's interface address (`resolve_ip_for_localhost`). Its own single-node
    switch is `RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`, read once at import into
    `ray_constants.ENABLE_RAY_CLUSTER`; we set that attribute for the duration of `ray.init` only,
    since attaching to a real cluster later in the same process needs the interface address."""
    import ray._private.ray_constants as ray_constants  # lazy: heavy (ray); private: see the NOTE

    before = ray_constants.ENABLE_RAY_CLUSTER
    ray_constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = before


def _is_loopback(address: str) -> bool:
    """Whether a Ray address (`host:port`, maybe `ray://`) names this machine's loopback."""
    host = address.split("://")[-1].rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def connect(mode: str, explicit_address: str, num_actors: int, actor_cpus: float, learner_replicas: int = 1) -> RayContext:
    """Attach to a running cluster or start a private local Ray instance, per `mode`."""
    import ray  # lazy: heavy (ray), only in the Ray modes

    found = None if mode == "local" else find_running_cluster(explicit_address)
    reaper = None
    if found is not None:
        address, how = found
        print(f"[morphmimic] attaching to the running Ray cluster at {address} (found via {how})", flush=True)
        if how != "--ray-address":
            _use_token_auth_if_available()
        # NOTE: a cluster on loopback (`local-cluster`, `ray start --node-ip-address 127.0.0.1`) has
        # its raylets at 127.0.0.1; the driver must take that address too to find them.
        on_loopback = loopback_only() if _is_loopback(address) else contextlib.nullcontext()
        with on_loopback:
            ray.init(address=address, logging_level=logging.WARNING, log_to_driver=True)
        kind = "cluster"
    elif mode == "cluster":
        raise RuntimeError(
            "--mode cluster: no running Ray cluster found (no --ray-address, no RAY_ADDRESS, no live `ray start` "
            "on this machine). Start one with `ray start --head` or use --mode local."
        )
    else:
        cpus = max(2, int(num_actors * actor_cpus + 0.999))
        print(f"[morphmimic] no Ray cluster to attach to: starting a private local Ray instance ({cpus} CPUs, "
              "loopback only)", flush=True)
        _token_auth_for_local_instance()
        with loopback_only():
            ray.init(
                address="local",
                num_cpus=cpus,
                resources={ROLLOUT_RESOURCE: float(num_actors), SAMPLER_RESOURCE: 1.0,
                           **({LEARNER_RESOURCE: float(learner_replicas - 1)} if learner_replicas > 1 else {})},
                include_dashboard=False,
                dashboard_host="127.0.0.1",
                logging_level=logging.WARNING,
            )
        # NOTE: the session directory has no public accessor; every process of the instance names it
        reaper = ray_reaper.start(ray._private.worker._global_node.get_session_dir_path())
        kind = "local"
    resources = {k: float(v) for k, v in ray.cluster_resources().items() if not k.startswith("node:")}
    ips = tuple(sorted({n["NodeManagerAddress"] for n in ray.nodes() if n.get("Alive")}))
    print(f"[morphmimic] Ray {kind}: address {ray.get_runtime_context().gcs_address}, nodes {list(ips)}", flush=True)
    print(f"[morphmimic] resources: {', '.join(f'{k}={v:g}' for k, v in sorted(resources.items()))}", flush=True)
    return RayContext(kind, ray.get_runtime_context().gcs_address, resources, ips, reaper)


def bind_host(ctx: RayContext | None, override: str) -> str:
    """127.0.0.1 when every node is on this machine (or no Ray), else this node's IP."""
    if override:
        return override
    if ctx is None:
        return "127.0.0.1"
    import ray  # lazy: heavy (ray), only in the Ray modes

    here = ray.util.get_node_ip_address()
    return "127.0.0.1" if set(ctx.node_ips) <= {here} else here


def actor_options(ctx: RayContext, resource: str, amount: float, num_cpus: float) -> dict:
    """Ray options that place an actor by custom resource, or spread it when the cluster has none."""
    if ctx.resources.get(resource, 0.0) > 0:
        return {"num_cpus": num_cpus, "resources": {resource: amount}}
    log.warning("cluster has no %r resource: spreading actors over nodes instead (see deploy/README.md)", resource)
    return {"num_cpus": num_cpus, "scheduling_strategy": "SPREAD"}


def shutdown(ctx: RayContext | None) -> None:
    import ray  # lazy: heavy (ray), only in the Ray modes

    if ctx is not None and ray.is_initialized():
        ray.shutdown()
    if ctx is not None and ctx.reaper is not None:
        ctx.reaper.close()


def start_test_cluster(rollout_per_worker: int = 1, cpus_per_worker: int = 1, learner_slots: int = 1, workers: int = 2):
    """A Ray head and `workers` worker nodes, all on this machine (loopback), tagged with the
    custom resources the learner places by: the head hosts the sampler and up to
    `learner_slots` data-parallel learner replicas, each worker `rollout_per_worker` rollout
    actors on `cpus_per_worker` CPUs. Returns the `ray.cluster_utils.Cluster` (its `address`;
    `shutdown()` stops every node). The local two-worker test cluster (`morphmimic local-cluster`)
    and the scaling and soak benchmarks run on it."""
    from ray.cluster_utils import Cluster  # lazy: heavy (ray), only when a test cluster is wanted

    with loopback_only():  # every node at 127.0.0.1: each server binds loopback only
        cluster = Cluster(
            initialize_head=True,
            connect=False,
            head_node_args={"num_cpus": 0, "resources": {SAMPLER_RESOURCE: 1, LEARNER_RESOURCE: learner_slots},
                            "include_dashboard": False, "node_ip_address": LOOPBACK},
        )
        for _ in range(workers):
            cluster.add_node(num_cpus=cpus_per_worker, resources={ROLLOUT_RESOURCE: rollout_per_worker},
                             node_ip_address=LOOPBACK)
        cluster.wait_for_nodes()
    return cluster
