"""Counters a peer cannot forge (issue 54, item 3), over real ZeroMQ on 127.0.0.1: a sequence
jump no unroll could make is refused and counted, never added to the lost-unroll count; a
spoofed seq 0 does not turn the actor's next real unroll into a gap over its whole sequence; an
honest actor is never blocked by either; and under CURVE an actor's key speaks only for its own
actor id."""

from __future__ import annotations

import zmq

from common import sockets, wire
from common.curve_keys import RunKeys, make_client
from learner.transport import MAX_SEQ_JUMP
from tests.learner.test_transport import N, T, _drain, _push, _transport, _unroll


def _heartbeat(seq: int, actor_id: int = 1, final: bool = False) -> list:
    return wire.encode(wire.HeartbeatMsg(actor_id=actor_id, seq=seq, env_steps=0, final=final))


def test_a_heartbeat_of_seq_2_to_the_53_is_refused_and_adds_no_gap() -> None:
    t = _transport()
    push = _push(t)
    try:
        for seq in range(10):
            push.send_multipart(wire.encode(_unroll(seq)))
        push.send_multipart(_heartbeat(2**53))
        push.send_multipart(_heartbeat(2**53, final=True))
        for seq in (10, 11):
            push.send_multipart(wire.encode(_unroll(seq)))
        got = _drain(t, rounds=20)
        assert [u.seq for u in got] == list(range(12))
        assert t.counters["rejected/seq_jump"] == 2
        assert t.lost() == 0 and t.counters["seq_restarts"] == 0
        assert t.finals == {} and t.last_seq == {1: 11}
    finally:
        push.close()
        t.close()


def test_a_spoofed_seq_0_adds_no_gap_and_real_losses_still_count() -> None:
    """Actor 1 sent 0..9; a peer sends its seq 0 (an unroll and a heartbeat). Its next real
    unroll, 10, is no gap of 10; a real loss after that (12) still counts as one."""
    t = _transport()
    push = _push(t)
    try:
        for seq in range(10):
            push.send_multipart(wire.encode(_unroll(seq)))
        push.send_multipart(wire.encode(_unroll(0)))  # spoofed
        push.send_multipart(_heartbeat(0))  # spoofed
        for seq in (10, 11, 13):
            push.send_multipart(wire.encode(_unroll(seq)))
        got = _drain(t, rounds=20)
        assert len(got) == 14
        assert t.lost() == 1  # 12 only
        assert t.counters["seq_restarts"] == 1 and t.last_seq == {1: 13}
    finally:
        push.close()
        t.close()


def test_an_honest_actor_is_never_blocked_by_a_refused_number() -> None:
    """An actor whose ledger numbers on from an earlier session (its first number is far past
    anything this learner saw) loses one unroll, refused and counted, then is taken again; an
    actor without a ledger that restarts from 0 keeps counting its own losses."""
    t = _transport()
    push = _push(t)
    try:
        start = 5 * MAX_SEQ_JUMP
        for seq in (start, start + 1, start + 2):
            push.send_multipart(wire.encode(_unroll(seq, actor_id=0)))
        for seq in (0, 1, 2, 3):  # actor 1 before its restart
            push.send_multipart(wire.encode(_unroll(seq)))
        for seq in (0, 1, 3):  # after it: 2 of the new numbering is lost
            push.send_multipart(wire.encode(_unroll(seq)))
        got = _drain(t, rounds=20)
        assert [(u.actor_id, u.seq) for u in got] == [(0, start + 1), (0, start + 2), *((1, s) for s in (0, 1, 2, 3, 0, 1, 3))]
        assert t.counters["rejected/seq_jump"] == 1
        assert t.lost() == 1 and t.counters["seq_restarts"] == 1
    finally:
        push.close()
        t.close()


def _keyed_push(endpoint: str, keys: RunKeys, role: str) -> zmq.Socket:
    push = zmq.Context.instance().socket(zmq.PUSH)
    make_client(push, keys, role)
    push.setsockopt(zmq.LINGER, 1000)
    push.connect(endpoint)
    return push


def test_under_curve_an_actors_key_speaks_only_for_its_own_id() -> None:
    """Actor 0's key claims actor 1 (an unroll, a heartbeat with a huge seq, a final
    heartbeat): each is refused as `wrong_actor_key` and moves none of actor 1's counters; the
    learner's own client key speaks for no actor; actor 1's key is taken as actor 1."""
    keys = RunKeys.generate(2)
    t = _transport(keys=keys)
    actor0 = sockets.connect_unroll_push(t.endpoints["unrolls"], keys.for_actor(0))
    learner = _keyed_push(t.endpoints["unrolls"], keys, "learner")
    actor1 = sockets.connect_unroll_push(t.endpoints["unrolls"], keys.for_actor(1))
    try:
        actor0.send_multipart(wire.encode(_unroll(0, actor_id=0)))
        actor0.send_multipart(wire.encode(_unroll(0, actor_id=1)))
        actor0.send_multipart(_heartbeat(2**40))
        actor0.send_multipart(_heartbeat(5, final=True))
        learner.send_multipart(wire.encode(_unroll(1, actor_id=0)))
        actor1.send_multipart(wire.encode(_unroll(0, actor_id=1)))
        got = []
        for _ in range(100):
            got += t.receive(50, 0, 1)
            if len(got) == 2 and t.counters["rejected/wrong_actor_key"] == 4:
                break
        assert sorted((u.actor_id, u.seq) for u in got) == [(0, 0), (1, 0)]
        assert t.counters["rejected/wrong_actor_key"] == 4
        assert t.lost() == 0 and t.finals == {} and t.last_seq == {0: 0, 1: 0}
        assert got[0].rewards.shape == (T, N)
    finally:
        for sock in (actor0, learner, actor1):
            sock.close(linger=0)
        t.close()
