"""Only members get in (issue 22, item 2): with a run's CURVE keys, the learner's and the
sampler's sockets admit only that run's clients, count every refused peer, and the sampler
takes state-changing requests only from the learner. Real sockets on 127.0.0.1."""

from __future__ import annotations

import time

import numpy as np
import pytest
import zmq

from common import sockets, wire
from common.curve_keys import ACTOR, LEARNER, RunKeys, make_server
from common.params import ParamSpace
from common.rpc import ServiceUnavailable
from sampler.client import SamplerClient
from sampler.config import SamplerConfig
from sampler.service import SamplerService
from tests.learner.test_transport import N, T, _transport, _unroll


def _receive_until(t, predicate, rounds: int = 200) -> list:
    got = []
    for _ in range(rounds):
        got += t.receive(50, 0, 1)
        if predicate(got):
            break
    return got


def _auth_refusals(counters, prefix: str = "") -> int:
    return sum(v for k, v in counters.items() if k.startswith(prefix + "auth_"))


def _stranger_push(endpoint: str, keys: RunKeys | None) -> zmq.Socket:
    """A PUSH that is not one of the run's actors: no keys at all, or keys of its own."""
    sock = zmq.Context.instance().socket(zmq.PUSH)
    sock.setsockopt(zmq.LINGER, 0)
    if keys is not None:
        sock.curve_serverkey, sock.curve_publickey, sock.curve_secretkey = keys.server_public, keys.actor_public, keys.actor_secret
    sock.connect(endpoint)
    return sock


def test_the_split_keys_hold_only_what_each_part_needs() -> None:
    keys = RunKeys.generate(3)
    actors, sampler = keys.for_actor(2), keys.for_sampler()
    assert actors.server_secret == b"" and actors.learner_secret == b"" and actors.actor_keys == ()
    assert (actors.actor_public, actors.actor_secret) == keys.actor_keys[2] and actors.actor_id == 2
    assert len({secret for _, secret in keys.actor_keys}) == 3  # a pair per actor
    assert sampler.learner_secret == b"" and sampler.actor_secret == b"" and sampler.server_secret == keys.server_secret
    assert all(secret == b"" for _, secret in sampler.actor_keys) and len(sampler.roles()) == 4
    with pytest.raises(ValueError, match="no actor's secret"):
        sampler.for_actor(0)
    with pytest.raises(ValueError, match="actors 0..2"):
        keys.for_actor(3)
    sock = zmq.Context.instance().socket(zmq.PULL)
    with pytest.raises(ValueError, match="no server secret"):
        make_server(sock, actors)
    sock.close(linger=0)
    with pytest.raises(ValueError, match="no learner secret"):
        actors.client_pair(LEARNER)


@pytest.mark.parametrize("stranger", ["no keys", "another run's keys", "a made-up client key"])
def test_the_unroll_socket_admits_this_runs_actors_and_counts_strangers(stranger: str) -> None:
    keys = RunKeys.generate(2)
    t = _transport(keys=keys)
    try:
        if stranger == "no keys":
            intruder_keys = None
        elif stranger == "another run's keys":
            intruder_keys = RunKeys.generate()
        else:  # the right server key, but a client key the run never made
            public, secret = zmq.curve_keypair()
            intruder_keys = RunKeys(keys.server_public, b"", b"", b"", public, secret)
        intruder = _stranger_push(t.endpoints["unrolls"], intruder_keys)
        for seq in range(3):
            intruder.send_multipart(wire.encode(_unroll(seq, actor_id=0)), flags=zmq.NOBLOCK) if intruder.poll(0, zmq.POLLOUT) else None
        got = _receive_until(t, lambda g: _auth_refusals(t.counters, "rejected/") > 0)
        assert got == [], "a stranger's unroll reached the learner"
        assert _auth_refusals(t.counters, "rejected/") >= 1, dict(t.counters)
        member = sockets.connect_unroll_push(t.endpoints["unrolls"], keys.for_actor(1))
        member.send_multipart(wire.encode(_unroll(0, actor_id=1)))
        got = _receive_until(t, lambda g: len(g) > 0)
        assert len(got) == 1 and got[0].rewards.shape == (T, N)
        intruder.close(linger=0)
        member.close(linger=0)
    finally:
        t.close()


def test_weights_reach_members_only() -> None:
    keys = RunKeys.generate()
    t = _transport(keys=keys)
    try:
        member = sockets.connect_weights_sub(t.endpoints["weights_pub"], keys.for_actor(0))
        stranger = zmq.Context.instance().socket(zmq.SUB)
        stranger.setsockopt(zmq.SUBSCRIBE, b"")
        stranger.setsockopt(zmq.LINGER, 0)
        stranger.connect(t.endpoints["weights_pub"])
        msg = wire.WeightsMsg(policy_version=1, tensors={"w": np.ones(3, np.float32)})
        got_member = got_stranger = False
        for _ in range(60):  # PUB drops to peers not yet joined: publish until the member hears
            t.publish(msg)
            t.receive(20, 0, 1)
            got_member = got_member or bool(member.poll(20, zmq.POLLIN))
            got_stranger = got_stranger or bool(stranger.poll(0, zmq.POLLIN))
            if got_member and _auth_refusals(t.counters, "rejected/"):
                break
        assert got_member and not got_stranger
        assert _auth_refusals(t.counters, "rejected/") >= 1
        member.close(linger=0)
        stranger.close(linger=0)
    finally:
        t.close()


def test_the_sampler_takes_state_changes_from_the_learner_only() -> None:
    keys = RunKeys.generate()
    space = ParamSpace(("a",), (0.0,), (1.0,), (0.5,))
    service = SamplerService(SamplerConfig(n_mcmc=64, n_chains=4, burn_in=4), space, keys=keys.for_sampler())
    # NOTE: members wait long (a loaded machine may be slow to serve); only the stranger times out
    actor = SamplerClient(service.endpoint, timeout_s=5.0, retries=1, keys=keys.for_actor(0), role=ACTOR)
    learner = SamplerClient(service.endpoint, timeout_s=5.0, retries=1, keys=keys, role=LEARNER)
    stranger = SamplerClient(service.endpoint, timeout_s=0.3, retries=1)
    results = {}

    def serve_while(call):
        import threading

        out = {}
        th = threading.Thread(target=lambda: out.update(r=_capture(call)))
        th.start()
        deadline = time.monotonic() + 10
        while th.is_alive() and time.monotonic() < deadline:
            service.serve_pending(20)
        th.join(5)
        return out.get("r")

    try:
        results["actor draws"] = serve_while(lambda: actor.draw(4))
        results["actor reports"] = serve_while(lambda: actor.report(np.zeros((2, 1), np.float32), np.ones(2, np.float32)))
        results["actor ticks"] = serve_while(lambda: actor.tick(1))
        results["actor reads state"] = serve_while(lambda: actor.get_state())
        results["learner reports"] = serve_while(lambda: learner.report(np.zeros((2, 1), np.float32), np.ones(2, np.float32)))
        results["stranger draws"] = serve_while(lambda: stranger.draw(4))
        service.serve_pending(50)
        stats = service.stats()
    finally:
        for c in (actor, learner, stranger):
            c.close()
        service.close()
    assert results["actor draws"].params.shape == (4, 1)
    for what in ("actor reports", "actor ticks", "actor reads state"):
        assert isinstance(results[what], wire.WireError) and "taken only from learner" in str(results[what]), \
            (what, results[what])
    assert str(results["learner reports"]).startswith("stored 2 pairs")  # the service's note
    assert isinstance(results["stranger draws"], ServiceUnavailable)
    assert stats["requests/rejected/forbidden"] == 3.0
    assert sum(v for k, v in stats.items() if k.startswith("requests/rejected/auth_")) >= 1


def _capture(call):
    try:
        return call()
    except Exception as exc:  # noqa: BLE001 - the test inspects what was raised
        return exc
