"""The learner's sockets: PULL for unrolls, PUB for weights, ROUTER for weight snapshots.

Every received message is decoded and validated here (`wire.decode` with the configuration's
T, N and sizes pinned, then the actor id, under CURVE the key it came with, its sequence number,
and an unroll's content against its task's bounds, `learner/unroll_bounds.py`); what fails is
counted under `rejected/<kind>` and logged once per kind, and nothing raised while accepting a
message ever leaves `receive` (`rejected/internal` counts our own bugs). Nothing malformed or
out of its task's bounds reaches the optimizer, the counters or the sampler.

Loss accounting: each actor numbers its unrolls (`UnrollMsg.seq`, durable across restarts with
`actors/seq_ledger.py`). A number skipped by an unroll, or covered by a heartbeat's `seq` but
never received, is a lost unroll: `seq_gap_unrolls`. At stop, `drain` reads the socket until
every actor's final heartbeat arrived (or it stays quiet): what arrives is counted, and the final
heartbeat's `seq` exposes the tail an actor numbered but the learner never got. A number counted
as a gap that arrives after all (a restarted actor's new connection read before its old one's
last unroll) is taken back from the gaps and counted as `late_unrolls`.

Every received unroll is trained on (`unrolls_trained`), dropped as stale (`stale_unrolls`), or
left unused: at a stop (`unused_at_stop`), or by a session killed after a checkpoint that
recorded it waiting for the next batch (`unused_at_resume`).

A number is judged against what the actor could have sent (`_advance`): a jump of more than
`MAX_SEQ_JUMP` is refused (`rejected/seq_jump`) and never counted as a gap, and a number below
the actor's numbering (a restart, or a spoofed seq 0) never lowers the high-water mark that the
actor's next unroll is counted from.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import time
from collections.abc import Callable

import zmq

from common import sockets, wire
from common.curve_keys import RefusalCounter, RunKeys, actor_user_id, role_of
from common.rpc import RouterServer
from common.socket_events import ConnectionEvents
from learner.unroll_bounds import UnrollBounds

log = logging.getLogger(__name__)

MAX_SEQ_JUMP = 1024
"""Most unroll numbers one message may skip. An honest gap is the few unrolls queued between a
dying actor and the learner (ZeroMQ's queues hold 4 each way), one per crash before a send, or
unrolls the codec refused; a larger jump is refused, not counted as lost unrolls."""

MAX_MISSING = 4 * MAX_SEQ_JUMP
"""Most gap numbers remembered per actor, so that a late arrival can be taken back from the gaps."""


class LearnerTransport:
    def __init__(self, host: str, obs_dim: int, act_dim: int, n_params: int, port_base: int = 0, *,
                 unroll_length: int, envs_per_actor: int, num_actors: int, keys: RunKeys | None = None,
                 bounds: UnrollBounds | None = None, max_msg_bytes: int = sockets.UNROLL_MAX_BYTES):
        """`port_base` 0 binds free ports; else unrolls on port_base, weights PUB on +1, snapshots on +2.

        An unroll must be `[unroll_length, envs_per_actor, ...]` with these obs/act/param sizes,
        and come (like a heartbeat) from an actor id in `[0, num_actors)`: anything else is a
        counted rejection, never a new actor in the health counters. `keys`: the run's CURVE
        keys; with them every socket admits only this run's clients, a peer the handshake
        refuses is counted as `rejected/auth_*` (`common.curve_keys`), and an actor's unrolls and
        heartbeats are taken only under its own key (`rejected/wrong_actor_key`). `bounds`: the
        task's content bounds; an unroll outside them is dropped whole (`rejected/bounds_*`).
        `max_msg_bytes`: the largest unroll-channel message libzmq takes (larger ones drop the
        peer's connection)."""
        addr = lambda i: f"tcp://{host}:{port_base + i}" if port_base else f"tcp://{host}"  # noqa: E731
        self.pull, unrolls = sockets.bind_unroll_pull(addr(0), keys, max_msg_bytes)
        self.pub, weights_pub = sockets.bind_weights_pub(addr(1), keys)
        router, weights_router = sockets.bind_router(addr(2), keys)
        self.refusals = [RefusalCounter(self.pub)] if keys is not None else []
        """Handshakes refused on the PUB socket (the PULL's are in `connections`, the ROUTER's in `snapshots`)."""
        self.connections = ConnectionEvents(self.pull, with_refusals=keys is not None)
        """The PULL's refused handshakes (`rejected/auth_*`) and ended connections
        (`disconnects`): an actor that stopped or restarted, or a peer libzmq dropped for a
        message over `max_msg_bytes`, which would otherwise vanish without a trace."""
        self.endpoints = {"unrolls": unrolls, "weights_pub": weights_pub, "weights_router": weights_router}
        self.snapshots = RouterServer(router, self._on_request, name="weights")
        self.dims = {"T": unroll_length, "N": envs_per_actor, "obs_dim": obs_dim, "act_dim": act_dim, "n_params": n_params}
        """Shape names of `UnrollMsg` pinned to the configuration (see `wire.decode`)."""
        self.num_actors = num_actors
        self.secured = keys is not None
        self.bounds = bounds
        self.current: wire.WeightsMsg | None = None
        self.counters: collections.Counter[str] = collections.Counter()
        self.last_seq: dict[int, int] = {}
        """Highest unroll sequence number received (or announced by a heartbeat) per actor."""
        self.numbering: dict[int, int] = {}
        """The number each actor's last accepted message reached: its high-water mark, or lower
        after a restart of its numbering (an actor without a ledger counts from 0 again)."""
        self.refused_at: dict[int, int] = {}
        """The number of an actor's last message refused as a jump: a next unroll that follows on
        from it is accepted, so one refused message never blocks an actor."""
        self.resumed = False
        """Set by `load_state_dict`: each actor's first message sets its baseline, not seq 0."""
        self.resume_marks: dict[int, int] = {}
        """Each actor's highest number in the checkpoint resumed from, until its first number past
        it: the numbers that one skips were sent to the session that died before checkpointing
        them (received after its last checkpoint, or in flight), `lost/unrolls_at_resume`, not
        wire gaps. The mark is the actor's high-water mark from the start, so a number below it
        (an actor numbering from 0 again, or a spoofed 0) cannot set a low baseline that the
        actor's real numbers would then seem to jump from."""
        self.resume_allowance = MAX_SEQ_JUMP
        """Most numbers an actor's first number past its resume mark may skip (more is refused as
        `seq_jump`); the run raises it by what the killed session's extra iterations could have
        numbered."""
        self.missing: dict[int, dict[int, str]] = {}
        """Per actor, the numbers booked as lost in its current numbering, with the counter each
        was booked under (`seq_gap_unrolls`, or `lost/unrolls_at_resume`); at most `MAX_MISSING`,
        the highest. One that arrives after all is taken back from its counter and counted as
        `late_unrolls`. Forgotten when the actor's numbering restarts from below."""
        self.received: collections.Counter[int] = collections.Counter()
        """Valid unrolls received per actor."""
        self.sampler_outages: dict[int, int] = {}
        """Latest cumulative sampler-outage count each actor reported."""
        self.sampler_outages_base = 0
        """Outages of actor processes that have since restarted (their count began again at 0)
        and of the sessions before a resume: `sampler_outages_total` adds it."""
        self.last_seen: dict[int, float] = {}
        """Known actors only: a message from an id outside the configuration is rejected first."""
        self.finals: dict[int, int] = {}
        """Actors that said they stopped (final heartbeat) and the last seq they numbered."""
        self.bytes_received = 0
        self.poller = zmq.Poller()
        self.poller.register(self.pull, zmq.POLLIN)
        self.poller.register(router, zmq.POLLIN)

    def _on_request(self, msg) -> wire.WeightsMsg | wire.ErrorMsg:
        if not isinstance(msg, wire.WeightsRequestMsg):
            raise wire.WireError(f"the weights service answers weights_request only, not {type(msg).KIND}", "unknown_kind")
        if msg.actor_id >= self.num_actors:
            raise wire.WireError(f"weights_request from actor {msg.actor_id}; this run has actors "
                                 f"0..{self.num_actors - 1}", "unknown_actor")
        if self.current is None:
            return wire.ErrorMsg(reason="no weights published yet; ask again", error_kind="not_ready")
        self.counters["snapshots_served"] += 1
        return self.current

    def publish(self, msg: wire.WeightsMsg) -> None:
        self.current = msg
        self.pub.send_multipart(wire.encode(msg), copy=False)

    def _reject(self, kind: str, reason: str) -> None:
        if self.counters[f"rejected/{kind}"] == 0:
            log.warning("rejected an unroll-channel message (%s): %s", kind, reason)
        self.counters[f"rejected/{kind}"] += 1

    def rejected(self) -> int:
        """Unroll-channel messages refused so far (every kind)."""
        return sum(v for k, v in self.counters.items() if k.startswith("rejected/"))

    def receive(self, timeout_ms: int, policy_version: int, max_policy_lag: int) -> list[wire.UnrollMsg]:
        """Serve snapshot requests and return the valid, fresh unrolls that arrive within
        `timeout_ms` (returns as soon as something arrived). Never raises over a peer's input."""
        out: list[wire.UnrollMsg] = []
        for refusals in self.refusals:
            refusals.poll(self.counters, prefix="rejected/")
        self.connections.poll(self.counters)
        deadline = time.monotonic() + timeout_ms / 1000
        events = dict(self.poller.poll(timeout_ms))
        while events:
            if self.snapshots.sock in events:
                self.snapshots.serve_pending(0)
            if self.pull in events:
                out += self._read(policy_version, max_policy_lag, 256)
            # NOTE: bounded by the deadline too: a peer that floods requests would otherwise keep
            # `events` set for ever, and the loop's caller could never see a stop signal.
            if out or time.monotonic() >= deadline:
                break
            events = dict(self.poller.poll(0))
        return out

    def _read(self, policy_version: int, max_policy_lag: int, limit: int) -> list[wire.UnrollMsg]:
        out = []
        for _ in range(limit):
            try:
                frames = self.pull.recv_multipart(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                break
            msg = self._accept(frames, policy_version, max_policy_lag)
            if msg is not None:
                out.append(msg)
        return out

    def _accept(self, frames, policy_version: int, max_policy_lag: int) -> wire.UnrollMsg | None:
        """One message from the unroll channel: the fresh unroll, or None (a heartbeat, a stale
        unroll, or a rejection: each counted). Raises nothing."""
        try:
            self.bytes_received += sum(len(f.buffer) for f in frames)
            msg = wire.decode(frames, expect=(wire.UnrollMsg, wire.HeartbeatMsg), dims=self.dims)
            if msg.actor_id >= self.num_actors:
                raise wire.WireError(f"{type(msg).KIND} from actor {msg.actor_id}; this run has actors "
                                     f"0..{self.num_actors - 1}", "unknown_actor")
            if self.secured and (holder := role_of(frames[0])) != actor_user_id(msg.actor_id):
                raise wire.WireError(f"{type(msg).KIND} claims actor {msg.actor_id} but came with the key of "
                                     f"{holder or 'nobody known'}; an actor's key speaks only for its own id",
                                     "wrong_actor_key")
            return self._book(msg, policy_version, max_policy_lag)
        except wire.WireError as exc:
            self._reject(exc.kind, str(exc))
        except Exception:  # a bug of ours must not let a peer stop training: counted, logged once
            if self.counters["rejected/internal"] == 0:
                log.exception("internal error while accepting an unroll-channel message")
            self.counters["rejected/internal"] += 1
        return None

    def _advance(self, actor_id: int, seq: int, unroll: bool) -> None:
        """Book sequence number `seq` of an actor: an unroll numbered `seq` arrived, or (a
        heartbeat) every number up to `seq` was sent before it on this pipe. Numbers that should
        have arrived by now and did not are lost unrolls (`seq_gap_unrolls`).

        The missing numbers are counted from the actor's high-water mark, or, for a number below
        it, from where its restarted numbering got to (an actor without a ledger restarts from 0,
        counted as `seq_restarts`, not as a loss). A number below both is a restart (an unroll)
        or old news (a heartbeat): it never lowers the high-water mark, so a spoofed seq 0 cannot
        make the actor's next real unroll look like a jump over its whole sequence. A message
        that would skip more than `MAX_SEQ_JUMP` numbers is refused (`WireError` "seq_jump") and
        counts no gap; a next unroll that follows on from the refused number is accepted (an
        actor whose ledger numbers on from an earlier session), a heartbeat never is. After a
        resume, an actor's first number past its checkpoint mark (`resume_marks`) books what it
        skips as `lost/unrolls_at_resume`, up to `resume_allowance`, instead of as a gap."""
        booked = self.missing.get(actor_id, {}).pop(seq, None) if unroll else None
        if booked is not None:
            # Booked as lost when a later number came first: a restarted actor's new connection
            # can be read before the last unrolls its killed process left queued on the old one
            # (a PULL socket takes turns between connections). Not lost after all.
            self.counters[booked] -= 1
            self.counters["late_unrolls"] += 1
            return
        if actor_id not in self.last_seq and self.resumed:
            mark = self.resume_marks.get(actor_id)
            if mark is not None:  # the checkpoint's high-water mark: what a low number cannot undercut
                self.last_seq[actor_id] = self.numbering[actor_id] = mark
            else:
                baseline = seq - 1 if unroll else seq  # a resumed learner's baseline
                if baseline >= 0:
                    self.last_seq[actor_id] = self.numbering[actor_id] = baseline
        high = self.last_seq.get(actor_id, -1)
        current = self.numbering.get(actor_id, high)
        due = seq - 1 if unroll else seq
        base = high if due >= high else current if due >= current else None
        resuming = actor_id in self.resume_marks and base == high
        limit = self.resume_allowance if resuming else MAX_SEQ_JUMP
        if base is not None and due - base > limit:
            refused = self.refused_at.get(actor_id)
            if refused is None or not unroll or not refused <= due <= refused + MAX_SEQ_JUMP:
                self.refused_at[actor_id] = seq
                raise wire.WireError(f"{'unroll' if unroll else 'heartbeat'} seq {seq} of actor {actor_id} skips "
                                     f"{due - base} numbers after {base}; allowed: at most {limit}",
                                     "seq_jump")
            base = refused
        self.refused_at.pop(actor_id, None)
        if resuming:
            # The first number past the checkpoint's mark: those skipped were numbered before the
            # resume and taken (received, or in flight) by the session that died, not lost on the wire.
            del self.resume_marks[actor_id]
            if base is not None and due > base:
                self.counters["lost/unrolls_at_resume"] += due - base
                self._remember_missing(actor_id, range(base + 1, due + 1), "lost/unrolls_at_resume")
                base = due
        if base is not None and due > base:
            gap = due - base
            if self.counters["seq_gap_unrolls"] == 0:
                log.warning("actor %d: %d unroll(s) lost (seq %d -> %d)", actor_id, gap, base, seq)
            self.counters["seq_gap_unrolls"] += gap
            self._remember_missing(actor_id, range(base + 1, due + 1), "seq_gap_unrolls")
        if unroll:
            if base is None:
                self.counters["seq_restarts"] += 1
                self.missing.pop(actor_id, None)  # the new numbering's numbers are not the old one's
            self.numbering[actor_id] = seq
        elif base is not None:
            self.numbering[actor_id] = due
        reached = self.numbering.get(actor_id, -1)
        if reached > high:
            self.last_seq[actor_id] = reached

    def _remember_missing(self, actor_id: int, numbers: range, counter: str) -> None:
        missing = self.missing.setdefault(actor_id, {})
        missing.update(dict.fromkeys(numbers[-MAX_MISSING:], counter))
        if len(missing) > MAX_MISSING:  # numbers only grow within one numbering: drop the lowest
            for n in sorted(missing)[:len(missing) - MAX_MISSING]:
                del missing[n]

    def _book(self, msg, policy_version: int, max_policy_lag: int) -> wire.UnrollMsg | None:
        if isinstance(msg, wire.UnrollMsg) and msg.policy_version > policy_version:
            raise wire.WireError(f"unroll of policy version {msg.policy_version}, newer than the learner's "
                                 f"{policy_version}", "out_of_range")
        self.last_seen[msg.actor_id] = time.monotonic()
        if isinstance(msg, wire.HeartbeatMsg):
            # A heartbeat travels on the unrolls' pipe, after them: every number up to its seq
            # that has not arrived never will.
            self._advance(msg.actor_id, msg.seq, unroll=False)
            self.counters["heartbeats"] += 1
            if msg.final:
                self.finals[msg.actor_id] = msg.seq
            return None
        self._advance(msg.actor_id, msg.seq, unroll=True)
        if self.bounds is not None:  # after booking its number: a dropped unroll is no lost unroll
            self.bounds.check(msg)
        self.received[msg.actor_id] += 1
        before = self.sampler_outages.get(msg.actor_id, 0)
        if msg.sampler_outages < before:  # a restarted actor process counts from 0 again
            self.sampler_outages_base += before
        self.sampler_outages[msg.actor_id] = msg.sampler_outages
        self.counters["unrolls_received"] += 1
        self.counters["steps_received"] += int(msg.rewards.size)
        if policy_version - msg.policy_version > max_policy_lag:
            self.counters["stale_unrolls"] += 1
            return None
        return msg

    def drain(self, policy_version: int, max_policy_lag: int, expect_final: set[int],
              quiet_s: float = 5.0, max_s: float = 30.0, between: Callable[[], None] | None = None,
              hold: Callable[[], contextlib.AbstractContextManager] = contextlib.nullcontext) -> int:
        """At stop, after the actors were told to stop: read the unroll channel until every actor
        in `expect_final` sent its final heartbeat, or nothing arrived for `quiet_s`, or `max_s`
        passed. Everything read is booked as usual (gaps, rejections); fresh unrolls are counted
        as `drained_at_stop` and `unused_at_stop`. `between()` runs between reads (serial mode
        sends its actors' final heartbeats there). Each read and its counts run under `hold()` (the
        run's `StopFlag.held`: a second signal ends the drain between reads, never between an
        unroll's being received and its being counted). Returns the number of fresh unrolls drained."""
        start = last = time.monotonic()
        drained = 0
        while not expect_final <= self.finals.keys():
            now = time.monotonic()
            if now - last > quiet_s or now - start > max_s:
                missing = sorted(expect_final - self.finals.keys())
                log.warning("drain at stop: no final heartbeat from actor(s) %s after %.1f s", missing, now - start)
                break
            if between is not None:
                between()
            if self.pull.poll(50, zmq.POLLIN):
                before = self.counters.total()
                with hold():
                    got = self._read(policy_version, max_policy_lag, 256)
                    drained += len(got)
                    self.counters["drained_at_stop"] += len(got)
                    self.counters["unused_at_stop"] += len(got)
                if self.counters.total() != before:
                    last = time.monotonic()
            self.snapshots.serve_pending(0)
        self.connections.poll(self.counters)
        return drained

    def lost(self) -> int:
        """Unrolls numbered by an actor that never arrived (counted sequence gaps)."""
        return self.counters["seq_gap_unrolls"]

    def sampler_outages_total(self) -> int:
        """Sampler outages the actors counted over the whole run (restarts and resumes included)."""
        return self.sampler_outages_base + sum(self.sampler_outages.values())

    def state_dict(self) -> dict:
        """What a resumed learner needs to keep its counters where it left off: every counter
        family of this transport, the snapshot server's included."""
        return {
            "last_seq": {str(k): int(v) for k, v in self.last_seq.items()},
            "counters": {k: int(v) for k, v in self.counters.items()},
            "snapshot_rejected_counters": {k: int(v) for k, v in self.snapshots.rejected.items()},
            "snapshot_dropped_counters": {k: int(v) for k, v in self.snapshots.dropped.items()},
            "snapshots_served": int(self.snapshots.served),
            "bytes_received": int(self.bytes_received),
            "sampler_outages": int(self.sampler_outages_total()),
        }

    def load_state_dict(self, state: dict) -> None:
        """Counters, and the checkpoint's `last_seq` as each actor's resume mark. Each actor's
        first message after a resume is its new baseline: the numbers it skips beyond the mark
        are not wire gaps but work the previous session took and lost with it (a clean stop
        checkpoints after its drain, so they are none), counted as `lost/unrolls_at_resume`."""
        self.last_seq, self.numbering, self.refused_at = {}, {}, {}
        self.resume_marks = {}
        marks = state.get("last_seq")
        for k, v in (marks.items() if isinstance(marks, dict) else ()):
            if str(k).isdigit() and isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2**53:
                self.resume_marks[int(k)] = v
        self.resumed = True
        self.counters.update(state["counters"])
        # Unrolls the checkpointed session had received but not yet trained on (the run's
        # `pending_unrolls`, checked by `checkpoint_check`): left unused by the session that died.
        self.counters["unused_at_resume"] += int(state.get("pending_unrolls", 0))
        self.snapshots.rejected.update(state.get("snapshot_rejected_counters", {}))
        self.snapshots.dropped.update(state.get("snapshot_dropped_counters", {}))
        self.snapshots.served += int(state.get("snapshots_served", 0))
        self.bytes_received += int(state.get("bytes_received", 0))
        self.sampler_outages_base += int(state.get("sampler_outages", 0))

    def close(self) -> None:
        for refusals in self.refusals:
            refusals.close()
        self.connections.close()
        for sock in (self.pull, self.pub):
            sock.close(linger=0)
        self.snapshots.close()
