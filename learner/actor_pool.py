"""The rollout actors as the learner sees them: a pool that starts, keeps running, and stops
them. `RayActorPool` runs one `RolloutActor` per Ray actor process; `SerialActorPool` holds
them in this process and steps them from the learner's loop (serial mode)."""

from __future__ import annotations

import logging
from typing import Protocol

from actors.actor import RolloutActor
from common.curve_keys import RunKeys
from learner import cluster
from learner.config import RunConfig

log = logging.getLogger(__name__)


def _own_keys(keys: RunKeys | None, actor_id: int) -> RunKeys | None:
    """What actor `actor_id` may hold of the run's keys: the server's public key and its own pair,
    which speaks for its id only (the learner refuses its messages under another id)."""
    return keys.for_actor(actor_id) if keys is not None else None


class ActorPool(Protocol):
    def pump(self) -> None: ...

    def alive(self) -> int: ...

    def stats(self, timeout_s: float = 30.0) -> list[dict]: ...

    def stop(self, timeout_s: float = 15.0) -> None: ...


class SerialActorPool:
    def __init__(self, cfg: RunConfig, endpoints: dict[str, str], keys: RunKeys | None = None):
        """`keys`: the run's CURVE keys; each actor gets only its own pair (`RunKeys.for_actor`)."""
        self.actors = [
            RolloutActor(i, cfg.task, cfg.policy, cfg.actors, endpoints, seed=cfg.seed + 1000 * (i + 1),
                         keys=_own_keys(keys, i))
            for i in range(cfg.actors.num_actors)
        ]
        self.restarts = 0
        """Always 0 here (a failing actor fails the process); carries a resumed run's count."""

    def pump(self) -> None:
        """Each actor takes new weights (if any) and sends one unroll."""
        for actor in self.actors:
            actor.run_once(weights_timeout_ms=0)

    def alive(self) -> int:
        return len(self.actors)

    def stats(self, timeout_s: float = 30.0) -> list[dict]:
        return [a.stats() for a in self.actors]

    def stop(self, timeout_s: float = 15.0) -> None:
        for actor in self.actors:
            actor.close()


class RayActorPool:
    def __init__(self, cfg: RunConfig, endpoints: dict[str, str], ctx, sampler_name: str = "",
                 keys: RunKeys | None = None) -> None:
        """`sampler_name`: the sampler actor's Ray name (`SamplerHandle.ray_name`). `keys`: the run's
        CURVE keys; each actor is handed only its own pair (`RunKeys.for_actor`) through Ray (the
        cluster's own token authentication guards that channel)."""
        import ray  # lazy: heavy (ray), only in the Ray modes

        self.ray = ray
        remote_cls = ray.remote(RolloutActor)
        opts = cluster.actor_options(ctx, cluster.ROLLOUT_RESOURCE, 1.0, cfg.actors.num_cpus)
        self.handles = [
            remote_cls.options(max_concurrency=2, max_restarts=cfg.actor_max_restarts, **opts).remote(
                i, cfg.task, cfg.policy, cfg.actors, endpoints, cfg.seed + 1000 * (i + 1), sampler_name,
                _own_keys(keys, i)
            )
            for i in range(cfg.actors.num_actors)
        ]
        self.runs = {i: h.run.remote() for i, h in enumerate(self.handles)}
        self.restarts = 0
        """Actor failures the pool recovered from: one per failure, however many of the loop's
        resubmissions fail while Ray brings the process back (one kill used to count 3)."""
        self.dead: set[int] = set()
        self.recovering: dict[int, object] = {}
        """Actors whose process failed, and the probe (`stats`) whose answer shows it is back."""

    def pump(self) -> None:
        """Resubmit the loop of an actor whose `run` ended by a crash. Ray restarts the process
        (up to `actor_max_restarts` times, -1 = always, on any node with a free
        `morphmimic_rollout`); the loop call itself must be made again, and Ray holds it until
        the actor is back, so a lost node's actors return when capacity does."""
        self._check_recovering()
        refs = list(self.runs.values())
        done, _ = self.ray.wait(refs, num_returns=len(refs), timeout=0)
        for ref in done:
            i = next(k for k, v in self.runs.items() if v == ref)
            try:
                self.ray.get(ref)
                self.dead.add(i)  # returned normally: it was told to stop
                del self.runs[i]
            except self.ray.exceptions.RayError as exc:
                if self._gone_for_good(i):
                    log.error("rollout actor %d is dead and will not restart (%s)", i, type(exc).__name__)
                    self.dead.add(i)
                    del self.runs[i]
                    self.recovering.pop(i, None)
                    continue
                if i not in self.recovering:  # NOTE: loops resubmitted before Ray restarted it fail too: not counted again
                    self.restarts += 1
                    log.warning("rollout actor %d failed (%s); resubmitting its loop", i, type(exc).__name__)
                self.recovering[i] = self.handles[i].stats.remote()
                self.runs[i] = self.handles[i].run.remote()

    def _check_recovering(self) -> None:
        """An actor whose probe answered is back: its next failure is a new one."""
        if not self.recovering:
            return
        done, _ = self.ray.wait(list(self.recovering.values()), num_returns=len(self.recovering), timeout=0)
        for ref in done:
            i = next(k for k, v in self.recovering.items() if v == ref)
            try:
                self.ray.get(ref)
            except self.ray.exceptions.RayError:  # not back yet: probe again
                self.recovering[i] = self.handles[i].stats.remote()
            else:
                del self.recovering[i]

    def _gone_for_good(self, i: int) -> bool:
        try:
            from ray.util.state import get_actor  # lazy: heavy (ray's state API), only when an actor has failed

            state = get_actor(self.handles[i]._actor_id.hex(), timeout=10)
            return state is not None and state.state == "DEAD"
        except Exception:  # noqa: BLE001 - state API unavailable: assume Ray may restart it
            return False

    def alive(self) -> int:
        """Actors whose loop is submitted (running, or waiting for Ray to restart them)."""
        return len(self.runs)

    def stats(self, timeout_s: float = 30.0) -> list[dict]:
        refs = [self.handles[i].stats.remote() for i in self.runs]
        try:
            return self.ray.get(refs, timeout=timeout_s)
        except self.ray.exceptions.RayError as exc:
            log.warning("could not read actor stats: %s", exc)
            return []

    def stop(self, timeout_s: float = 15.0) -> None:
        """Tell every actor to stop, wait up to `timeout_s` for their loops, then kill them."""
        for h in self.handles:
            try:
                h.stop.remote()
            except self.ray.exceptions.RayError:
                pass
        try:
            self.ray.wait(list(self.runs.values()), num_returns=len(self.runs), timeout=timeout_s)
        except self.ray.exceptions.RayError:
            pass
        for h in self.handles:
            try:
                self.ray.kill(h, no_restart=True)
            except Exception:  # noqa: BLE001 - already gone
                pass
