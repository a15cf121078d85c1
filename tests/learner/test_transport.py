"""The learner's sockets under hostile input, over real ZeroMQ on 127.0.0.1: every bad message
is refused and counted by kind, sequence gaps and stale unrolls are counted, and the weight
snapshot service keeps answering."""

from __future__ import annotations

import dataclasses

import msgpack
import numpy as np
import zmq

from common import wire
from learner.transport import LearnerTransport


def _unroll(seq: int, version: int = 0, **kw) -> wire.UnrollMsg:
    z = lambda *s: np.zeros(s, np.float32)  # noqa: E731
    msg = wire.UnrollMsg(actor_id=1, seq=seq, policy_version=version, obs=z(2, 3, 4), next_obs=z(2, 3, 4),
                         actions=z(2, 3, 2), logp=z(2, 3), rewards=z(2, 3), terminated=np.zeros((2, 3), bool),
                         truncated=np.zeros((2, 3), bool), params=z(2, 3, 1))
    return dataclasses.replace(msg, **kw)


def _drain(t: LearnerTransport, version: int = 0, lag: int = 1, rounds: int = 40) -> list:
    out = []
    for _ in range(rounds):
        out += t.receive(50, version, lag)
    return out


def test_hostile_unroll_channel_input_is_counted_by_kind():
    t = LearnerTransport("127.0.0.1", obs_dim=4, act_dim=2, n_params=1)
    push = zmq.Context.instance().socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 1000)
    push.connect(t.endpoints["unrolls"])
    try:
        good = [bytes(f) for f in wire.encode(_unroll(0))]
        header = msgpack.unpackb(good[0])
        header["v"] = 9
        push.send_multipart([b"\xff\x00 not msgpack"])
        push.send_multipart(good[:4])
        push.send_multipart([msgpack.packb(header), *good[1:]])
        push.send_multipart(wire.encode(_unroll(1, rewards=np.full((2, 3), np.inf, np.float32))))
        push.send_multipart(wire.encode(_unroll(1, obs=np.zeros((2, 3, 5), np.float32))))
        push.send_multipart(wire.encode(wire.TickMsg(iteration=3)))
        push.send_multipart(good)  # seq 0: fine
        push.send_multipart(wire.encode(_unroll(3)))  # seq 1 and 2 never arrive
        push.send_multipart(wire.encode(_unroll(4, version=-5)))  # far too old
        got = _drain(t)
        c = t.counters
        assert [u.seq for u in got] == [0, 3]
        assert c["rejected/malformed"] == 2 and c["rejected/version"] == 1
        assert c["rejected/nonfinite"] == 1 and c["rejected/bad_shape"] == 1 and c["rejected/unknown_kind"] == 1
        assert c["seq_gap_unrolls"] == 2 and c["stale_unrolls"] == 1
        assert t.received[1] == 3
    finally:
        push.close()
        t.close()


def test_a_resumed_learner_keeps_its_counters_but_counts_no_gap_for_unrolls_after_its_checkpoint():
    """The checkpoint was written when actor 1 had sent seq 10; the learner trained on 11-19 and
    stopped; the actor's ledger numbers on from 20. Only a gap after that baseline counts."""
    before = LearnerTransport("127.0.0.1", obs_dim=4, act_dim=2, n_params=1)
    before.last_seq[1] = 10
    before.counters["seq_gap_unrolls"] = 3
    state = before.state_dict()
    before.close()
    t = LearnerTransport("127.0.0.1", obs_dim=4, act_dim=2, n_params=1)
    t.load_state_dict(state)
    push = zmq.Context.instance().socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 1000)
    push.connect(t.endpoints["unrolls"])
    try:
        for seq in (20, 21, 23):
            push.send_multipart(wire.encode(_unroll(seq)))
        assert [u.seq for u in _drain(t)] == [20, 21, 23]
        assert t.counters["seq_gap_unrolls"] == 3 + 1  # seq 22 only
    finally:
        push.close()
        t.close()


def test_snapshot_service_answers_garbage_with_errors_and_serves_weights():
    t = LearnerTransport("127.0.0.1", obs_dim=4, act_dim=2, n_params=1)
    dealer = zmq.Context.instance().socket(zmq.DEALER)
    dealer.setsockopt(zmq.LINGER, 0)
    dealer.connect(t.endpoints["weights_router"])
    try:
        def ask(frames):
            dealer.send_multipart([b"", *frames])
            for _ in range(100):
                t.receive(20, 0, 1)
                if dealer.poll(10):
                    return wire.decode(dealer.recv_multipart()[1:])
            raise AssertionError("no reply")

        assert isinstance(ask([b"junk"]), wire.ErrorMsg)
        assert ask(wire.encode(wire.WeightsRequestMsg(actor_id=0))).error_kind == "not_ready"
        t.publish(wire.WeightsMsg(policy_version=4, tensors={"w": np.ones(3, np.float32)}))
        reply = ask(wire.encode(wire.WeightsRequestMsg(actor_id=0)))
        assert isinstance(reply, wire.WeightsMsg) and reply.policy_version == 4
        assert t.snapshots.rejected["malformed"] == 1
    finally:
        dealer.close()
        t.close()
