"""`SamplerService`: the `ShapeSampler` behind a ZeroMQ ROUTER (DESIGN.md "Data flows").

Requests and their replies (messages of `common.wire`):
    DrawRequestMsg   -> DrawReplyMsg     n draws from the buffer (+ clip ids, + start times with
                                         time bins on)
    ValueReportMsg   -> OkMsg            (params, V) pairs (and each pair's clip, with shape_by_class)
                                         for the next Vm fit, training segments
                                         per clip and failure times; a resend with the same
                                         `report_id` is stored once (`reports/duplicates`); a bad
                                         failure time is refused alone, counted and named in the
                                         reply's `info`
    TickMsg          -> StatsReplyMsg    fit Vm, maybe refill; stats after the tick (a repeated
                                         iteration refits nothing and refills at most once)
    StatsRequestMsg  -> StatsReplyMsg
    StateRequestMsg  -> StateMsg         the whole state, for the learner's checkpoint
    StateMsg         -> OkMsg            restore that state: loaded into a copy and checked first,
                                         so a bad state is refused whole and changes nothing
    anything else    -> ErrorMsg         counted per kind in `requests/rejected/<kind>`; serving goes on

Every request is checked by `wire.decode` against its declared types and ranges (with
`n_params` pinned to this space), then by the sampler (draw sizes, parameter bounds). A refusal
is an `ErrorMsg` and a count; the service keeps answering.

The socket is used by one thread only (the one running `serve`), so the sampler needs no lock.
That thread also keeps the service's own state file (`config.state_dir`, `sampler/state_file.py`):
saved every `state_every_s` while requests change the state and on stop, loaded at start, so a
killed and restarted service comes back as it last saved instead of empty.
"""

from __future__ import annotations

import collections
import copy
import logging
import threading
import time
from typing import Any, Mapping, Sequence

import numpy as np
import zmq

from common import sockets, wire
from common.curve_keys import LEARNER, RunKeys
from common.params import ParamSpace
from common.rpc import RouterServer
from sampler import state_file
from sampler.config import SamplerConfig
from sampler.shape_sampler import ShapeSampler

log = logging.getLogger(__name__)


class SamplerFault(ValueError):
    """An unexpected exception inside the sampler while answering: replied as an error, logged
    with its traceback, and counted under `internal` instead of stopping the service."""

    kind = "internal"


def bind_address(config: SamplerConfig) -> str:
    """`tcp://host` (a free port) or `tcp://host:port` from the config."""
    return f"tcp://{config.host}" if config.port == 0 else f"tcp://{config.host}:{config.port}"


def _bind(address: str, keys: RunKeys | None = None, timeout_s: float = 5.0) -> tuple[zmq.Socket, str]:
    """Bind, retrying while the port is still held by a just-closed socket (a restart in place).

    NOTE: libzmq closes sockets asynchronously in its I/O thread, so re-binding the port of a
    service stopped a moment ago can fail with EADDRINUSE for a few milliseconds."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return sockets.bind_router(address, keys)
        except zmq.ZMQError as exc:
            if exc.errno != zmq.EADDRINUSE or time.monotonic() > deadline:
                raise RuntimeError(f"sampler cannot bind {address}: {exc}; choose another port or host") from exc
            time.sleep(0.05)


LEARNER_ONLY = (wire.ValueReportMsg, wire.TickMsg, wire.StateMsg, wire.StateRequestMsg)
"""Requests that change or read out the sampler's state: taken only from the learner's key
(an actor, or anything holding an actor's key, may draw and read stats)."""

REPORT_IDS_KEPT = 4096
"""Report ids remembered for deduplication (a retry follows its first try within seconds)."""


def _check_restored(s: ShapeSampler) -> None:
    """ValueError if a just-restored state could not serve: what `load_state_dict` takes as given
    (an index past the draw order would make `draw` loop forever)."""
    n = len(s.buffer)
    if s.buffer.ndim != 2 or n < 1 or not np.isfinite(s.buffer).all():
        raise ValueError(f"sampler state buffer of shape {s.buffer.shape}: expected [n >= 1, {s.space.dim}], finite")
    if s._order.shape != (n,) or not np.array_equal(np.sort(s._order), np.arange(n)):
        raise ValueError(f"sampler state order is not a permutation of the {n} buffer rows")
    if not 0 <= s._cursor <= n:
        raise ValueError(f"sampler state cursor = {s._cursor}; allowed: [0, {n}]")
    if s.class_names:
        per, classes = s.per_class, len(s.class_names)
        if n != per * classes:
            raise ValueError(f"sampler state buffer of {n} rows for {classes} classes: expected the same number per class")
        for c in range(classes):
            if not np.array_equal(np.sort(s._order[c * per:(c + 1) * per]), np.arange(c * per, (c + 1) * per)):
                raise ValueError(f"sampler state order of class {s.class_names[c]!r} is not a permutation of its rows")
        if s._class_cursor.shape != (classes,) or (s._class_cursor < 0).any() or (s._class_cursor > per).any():
            raise ValueError(f"sampler state class cursors {s._class_cursor.tolist()[:4]}: expected {classes}, "
                             f"each in [0, {per}]")
    if min(s.generation, s.draws_served, s.last_refill_iteration, s.last_tick + 1, s.pairs_taken, s.pairs_trimmed) < 0:
        raise ValueError("sampler state counters must not be negative")
    pending = [np.asarray(a) for a in (*s._pending_params, *s._pending_values)]
    if not all(np.isfinite(a).all() for a in pending):
        raise ValueError("sampler state pending pairs hold NaN or Inf")
    vm = s.vm
    numbers = [vm.mu, vm.sigma, vm.vbar, *vm.vbar_c, *vm.probe_std_c, *(float(p.detach().abs().max()) for p in vm.net.parameters())]
    if not np.isfinite(numbers).all() or not np.isfinite(vm.probe).all() or vm.sigma <= 0:
        raise ValueError("sampler state Vm holds NaN, Inf or a non-positive scale")


class SamplerService:
    """Owns a bound ROUTER and a `ShapeSampler`; `serve` answers until its stop event is set."""

    def __init__(self, config: SamplerConfig, space: ParamSpace,
                 clips: Sequence[tuple[str, str]] | None = None, address: str | None = None,
                 keys: RunKeys | None = None, durations: Mapping[str, float] | None = None):
        """`durations`: each clip's length in s, for start times (`ShapeSampler`). `address` overrides the config's host/port (e.g. `tcp://127.0.0.1:5555` to restart
        a service where its clients already look). `keys`: the run's CURVE keys as the sampler
        holds them (`RunKeys.for_sampler`): only this run's clients connect, and only the
        learner may change the sampler's state (`LEARNER_ONLY`)."""
        self.config = config
        self.sampler = ShapeSampler(config, space, clips, durations)
        self.reports: collections.OrderedDict[str, int] = collections.OrderedDict()
        """The `report_id`s of the last REPORT_IDS_KEPT stored reports and their pair counts."""
        self.duplicate_reports = 0
        self.started_unix_s = time.time()
        self.restored = False
        """True when this service began from its own state file (`config.state_dir`)."""
        self.saves = self.save_failures = 0
        if config.state_dir:
            self._restore_own_state()
        sock, self.endpoint = _bind(address or bind_address(config), keys)
        self.server = RouterServer(sock, self._handle, "sampler", dims={"n_params": space.dim},
                                   roles={kind: frozenset({LEARNER}) for kind in LEARNER_ONLY})
        self._saved_at = (time.monotonic(), self.server.served)
        if self.sampler.clips is not None:
            log.info("sampler: motion balancer over %d clips:\n%s", len(self.sampler.clips.clip_ids),
                     self.sampler.clips.table())
        log.info("sampler: serving %s on %s", list(space.names), self.endpoint)

    def _handle(self, msg: Any) -> Any:
        try:
            return self._dispatch(msg)
        except (wire.WireError, ValueError):
            raise
        except Exception as exc:  # a sampler bug must not take the service down with it
            log.exception("sampler: internal error on %s", type(msg).KIND)
            raise SamplerFault(f"internal error on {type(msg).KIND}: {type(exc).__name__}: {exc}") from exc

    def _dispatch(self, msg: Any) -> Any:
        s = self.sampler
        if isinstance(msg, wire.DrawRequestMsg):
            params, clips, starts = s.draw_episodes(msg.n)
            return wire.DrawReplyMsg(params=params.astype(np.float32), clip_ids=clips, start_s=starts,
                                     buffer_generation=s.generation)
        if isinstance(msg, wire.ValueReportMsg):
            if msg.report_id and msg.report_id in self.reports:
                # A retry whose first try was stored (the reply was lost): idempotent, like a tick.
                self.duplicate_reports += 1
                return wire.OkMsg(info=f"report {msg.report_id} already stored ({self.reports[msg.report_id]} pairs)")
            per_pair = {"pair_clips": msg.pair_clip_ids} if msg.pair_clip_ids else {}  # sent to shape_by_class only
            m = s.report(msg.params, msg.values, (msg.clip_ids, msg.clip_segments, msg.clip_tracked),
                         (msg.fail_clip_ids, msg.fail_times_s), **per_pair)
            if msg.report_id:
                self.reports[msg.report_id] = m
                while len(self.reports) > REPORT_IDS_KEPT:
                    self.reports.popitem(last=False)
            refused = s.refused_last
            return wire.OkMsg(info=f"stored {m} pairs" + (f"; refused {len(refused)} failure time(s), the first: {refused[0]}"
                                                          if refused else ""))
        if isinstance(msg, wire.TickMsg):
            s.tick(msg.iteration)
            return wire.StatsReplyMsg(stats=self.stats())
        if isinstance(msg, wire.StatsRequestMsg):
            return wire.StatsReplyMsg(stats=self.stats())
        if isinstance(msg, wire.StateRequestMsg):
            state = s.state_dict()
            return wire.StateMsg(meta=state["meta"], arrays=state["arrays"])
        if isinstance(msg, wire.StateMsg):
            self.sampler = self._restored({"meta": msg.meta, "arrays": msg.arrays})
            return wire.OkMsg(info=f"restored generation {self.sampler.generation}")
        raise wire.WireError(f"the sampler does not answer {type(msg).KIND!r} messages", "unknown_kind")

    def _restored(self, state: dict[str, Any]) -> ShapeSampler:
        """A copy of the sampler with `state` loaded and checked; ValueError naming what is wrong.
        NOTE: load_state_dict is not atomic: fill a copy, swap when sound."""
        restored = copy.deepcopy(self.sampler)
        try:
            restored.load_state_dict(state)
            _check_restored(restored)
        except ValueError:
            raise
        except Exception as exc:  # noqa: BLE001 - a missing key, a wrong type or shape: all the sender's
            raise ValueError(f"sampler state lacks or mistypes something ({type(exc).__name__}: {exc}); "
                             "send what StateRequestMsg returned") from None
        return restored

    def _restore_own_state(self) -> None:
        """Load the service's own state file, if `config.state_dir` has one that is sound."""
        state = state_file.load(self.config.state_dir)
        if state is None:
            return
        try:
            self.sampler = self._restored(state)
        except ValueError as exc:
            log.error("sampler: state file in %s refused (%s); starting without it", self.config.state_dir, exc)
            return
        self.restored = True
        log.info("sampler: restored its own state from %s (generation %d, %d pairs taken)",
                 state_file.path_in(self.config.state_dir), self.sampler.generation, self.sampler.pairs_taken)

    def save_state(self) -> bool:
        """Write the state file now (no-op without `config.state_dir`); False if it failed (logged, counted)."""
        if not self.config.state_dir:
            return False
        try:
            state_file.save(self.config.state_dir, self.sampler.state_dict())
        except Exception as exc:  # noqa: BLE001 - a full disk must not stop the service
            self.save_failures += 1
            log.error("sampler: could not save its state into %s: %s", self.config.state_dir, exc)
            return False
        self.saves += 1
        self._saved_at = (time.monotonic(), self.server.served)
        return True

    def _save_when_due(self) -> None:
        """Save when requests were served since the last save and `state_every_s` has passed."""
        at, served = self._saved_at
        if self.config.state_dir and self.server.served != served and time.monotonic() - at >= self.config.state_every_s:
            self.save_state()

    def stats(self) -> dict[str, float]:
        """`ShapeSampler.stats()` plus `requests/served`, `requests/rejected` (all kinds),
        `requests/rejected/<kind>` (malformed, version, unknown_kind, nonfinite, invalid, ...) and
        `requests/replies_dropped/<reason>` (full_pipe, departed, over_backlog); `state/saves`,
        `state/save_failures` (the state file), `state/restored` (1: this service began from its
        own state file) and `state/started_unix_s` (when this service began: a change tells the
        learner that the sampler restarted)."""
        out = self.sampler.stats()
        out["reports/duplicates"] = float(self.duplicate_reports)
        out["state/saves"] = float(self.saves)
        out["state/save_failures"] = float(self.save_failures)
        out["state/restored"] = float(self.restored)
        out["state/started_unix_s"] = self.started_unix_s
        out["requests/served"] = float(self.server.served)
        out["requests/rejected"] = float(sum(self.server.rejected.values()))
        for kind, count in sorted(self.server.rejected.items()):
            out[f"requests/rejected/{kind}"] = float(count)
        for reason, count in sorted(self.server.dropped.items()):  # replies a peer did not take (common.rpc)
            out[f"requests/replies_dropped/{reason}"] = float(count)
        return out

    def serve_pending(self, timeout_ms: int = 0) -> int:
        """Answer what arrives within `timeout_ms`; returns how many requests were handled."""
        return self.server.serve_pending(timeout_ms)

    def serve(self, stop_event: threading.Event, poll_ms: int = 50) -> None:
        """Answer requests until `stop_event` is set (checked every `poll_ms`), then close."""
        try:
            while not stop_event.is_set():
                self.server.serve_pending(poll_ms)
                self._save_when_due()
        finally:
            self.close()

    def close(self) -> None:
        """Save the state file (with `config.state_dir`), then release the socket."""
        if not self.server.sock.closed:
            self.save_state()
        self.server.close()
