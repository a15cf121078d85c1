"""The sampler service over real ZeroMQ sockets on 127.0.0.1: requests, bad input, restarts."""

import dataclasses
import threading
import time

import msgpack
import numpy as np
import pytest
import zmq

from common import sockets, wire
from common.params import ParamSpace
from common.rpc import ServiceUnavailable
from sampler.actor import start_in_thread
from common.motion.balancer import load_clip_labels
from sampler.client import SamplerClient
from sampler.config import SamplerConfig
from sampler.time_bins import END_MARGIN_S

SPACE = ParamSpace(names=("leg", "arm"), low=(0.5, 0.5), high=(2.0, 1.5))
CFG = SamplerConfig(p_mcmc=2, n_mcmc=200, n_chains=16, burn_in=20, vm_fit_steps=20, probe_points=128, seed=3)


@pytest.fixture
def service():
    svc, thread, stop = start_in_thread(CFG, SPACE, load_clip_labels())
    yield svc
    stop.set()
    thread.join(timeout=5)
    assert not thread.is_alive()


def raw_request(endpoint: str, frames: list) -> wire.ErrorMsg:
    """Send arbitrary frames from a bare DEALER and decode the reply."""
    sock = sockets.connect_dealer(endpoint)
    try:
        sock.send_multipart([b"", *frames])
        assert sock.poll(5000, zmq.POLLIN), "the service did not answer"
        return wire.decode(sock.recv_multipart()[1:])
    finally:
        sock.close(linger=0)


def test_client_calls(service):
    assert service.endpoint.startswith("tcp://127.0.0.1:")
    client = SamplerClient(service.endpoint, timeout_s=5.0)
    try:
        d = client.draw(8)
        assert d.params.shape == (8, 2) and d.params.dtype == np.float32 and len(d.clip_ids) == 8
        assert d.buffer_generation == 0
        client.report(d.params, np.linspace(10, 20, 8))
        stats = client.tick(2)
        assert stats["buffer/generation"] == 1 and stats["vm/pairs_seen"] == 8
        assert stats["draws/served"] == 8 and stats["requests/rejected"] == 0
        state = client.get_state()
        client.draw(50)
        client.set_state(state)
        assert client.stats()["draws/served"] == 8
    finally:
        client.close()


def test_restored_state_gives_identical_draws(service):
    client = SamplerClient(service.endpoint, timeout_s=5.0)
    try:
        state = client.get_state()
        first = client.draw(30)
        client.set_state(state)
        again = client.draw(30)
        np.testing.assert_array_equal(first.params, again.params)
        assert first.clip_ids == again.clip_ids
    finally:
        client.close()


def _bad_version_frames() -> list[bytes]:
    frames = [bytes(f) for f in wire.encode(wire.DrawRequestMsg(n=2))]
    header = msgpack.unpackb(frames[0])
    header["v"] = 99
    return [msgpack.packb(header), *frames[1:]]


def test_service_survives_bad_input_and_counts_it(service):
    ok_report = wire.encode(wire.ValueReportMsg(params=np.ones((3, 2), np.float32), values=np.ones(3, np.float32)))
    nan_params = np.array([[1.0, np.nan]], np.float32)
    cases = [
        ([b"\xc1garbage"], "malformed"),
        ([bytes(f) for f in ok_report[:-1]], "malformed"),  # truncated multipart: one array frame missing
        (_bad_version_frames(), "version"),
        (wire.encode(wire.ValueReportMsg(params=nan_params, values=np.ones(1, np.float32))), "nonfinite"),
        (wire.encode(wire.ValueReportMsg(params=np.array([[9.0, 1.0]], np.float32), values=np.ones(1, np.float32))),
         "invalid"),
        (wire.encode(wire.DrawRequestMsg(n=0)), "out_of_range"),  # refused by the wire rule (n >= 1)
        (wire.encode(wire.DrawRequestMsg(n=CFG.max_draw + 1)), "invalid"),  # by the sampler's own limit
        (wire.encode(wire.ValueReportMsg(params=np.ones((1, 3), np.float32), values=np.ones(1, np.float32))),
         "bad_shape"),  # n_params is pinned to the space's 2
        (wire.encode(wire.OkMsg(info="not a request")), "unknown_kind"),
    ]
    for frames, kind in cases:
        reply = raw_request(service.endpoint, [bytes(f) for f in frames])
        assert isinstance(reply, wire.ErrorMsg) and reply.error_kind == kind, (kind, reply)
    out_of_range = raw_request(service.endpoint, [bytes(f) for f in cases[4][0]])
    assert "'leg' = 9 is out of range; allowed: leg in [0.5, 2]" in out_of_range.reason
    client = SamplerClient(service.endpoint, timeout_s=5.0)
    try:
        assert client.draw(4).params.shape == (4, 2)  # still serving
        with pytest.raises(wire.WireError, match="out of range"):
            client.report(np.array([[0.1, 1.0]]), np.ones(1))
        stats = client.stats()
    finally:
        client.close()
    assert stats["requests/rejected"] == 11
    assert stats["requests/rejected/malformed"] == 2 and stats["requests/rejected/invalid"] == 4
    assert stats["requests/rejected/out_of_range"] == 1 and stats["requests/rejected/bad_shape"] == 1
    assert stats["requests/rejected/version"] == 1 and stats["requests/rejected/nonfinite"] == 1
    assert stats["vm/pending_pairs"] == 0


def test_client_survives_a_service_restart_on_the_same_endpoint():
    svc, thread, stop = start_in_thread(CFG, SPACE)
    endpoint = svc.endpoint
    client = SamplerClient(endpoint, timeout_s=0.5, retries=10)
    try:
        assert client.draw(2).params.shape == (2, 2)
        stop.set()
        thread.join(timeout=5)
        restarted: list = []

        def restart_later():
            time.sleep(0.7)  # the client's first tries time out against a dead endpoint
            restarted.append(start_in_thread(CFG, SPACE, address=endpoint))

        t = threading.Thread(target=restart_later)
        t.start()
        d = client.draw(3)  # blocks through the outage, then succeeds on the new service
        t.join()
        assert d.params.shape == (3, 2)
        assert client.rpc.reconnects >= 1
        svc2, thread2, stop2 = restarted[0]
        assert svc2.endpoint == endpoint and svc2.server.served >= 1
        stop2.set()
        thread2.join(timeout=5)
        # With nobody serving, the client gives up with ServiceUnavailable (actors then degrade).
        quick = SamplerClient(endpoint, timeout_s=0.2, retries=2)
        with pytest.raises(ServiceUnavailable):
            quick.draw(1)
        quick.close()
    finally:
        client.close()


def test_an_internal_error_is_replied_and_counted_not_fatal(service, monkeypatch):
    def broken_draw(n):
        raise RuntimeError("boom")

    client = SamplerClient(service.endpoint, timeout_s=5.0)
    try:
        monkeypatch.setattr(service.sampler, "draw", broken_draw)
        with pytest.raises(wire.WireError, match="internal error on draw_request: RuntimeError: boom"):
            client.draw(1)
        monkeypatch.undo()
        assert client.draw(2).params.shape == (2, 2)
        assert client.stats()["requests/rejected/internal"] == 1
    finally:
        client.close()


def test_a_resent_report_is_stored_once(service, monkeypatch):
    """The Lazy Pirate client resends a report whose reply it did not get in time; the service
    had stored the first one. The pairs must count once (keyed like `tick`: by the report's id)."""
    real_report = service.sampler.report
    calls = []

    def slow_first_report(params, values, clips=((), (), ()), failures=((), ())):
        calls.append(len(values))
        m = real_report(params, values, clips, failures)
        if len(calls) == 1:
            time.sleep(0.8)  # longer than the client's timeout: its first try times out
        return m

    monkeypatch.setattr(service.sampler, "report", slow_first_report)
    client = SamplerClient(service.endpoint, timeout_s=0.3, retries=5)
    try:
        d = client.draw(6)
        client.report(d.params, np.linspace(1, 2, 6))
        assert client.rpc.reconnects >= 1  # it did resend
        stats = client.stats()
        assert calls == [6]  # the resend was not stored again
        assert stats["vm/pending_pairs"] == 6 and stats["reports/duplicates"] >= 1
        client.report(d.params, np.linspace(1, 2, 6))  # a new report (new id) is stored
        assert client.stats()["vm/pending_pairs"] == 12
    finally:
        client.close()


def test_a_report_resent_by_hand_is_applied_once_and_a_new_id_is_not_deduplicated(service):
    report = wire.ValueReportMsg(params=np.ones((3, 2), np.float32), values=np.ones(3, np.float32), report_id="abc-1")
    frames = [bytes(f) for f in wire.encode(report)]
    for _ in range(3):
        assert isinstance(raw_request(service.endpoint, frames), wire.OkMsg)
    other = [bytes(f) for f in wire.encode(wire.ValueReportMsg(params=report.params, values=report.values))]
    for _ in range(2):  # no id: every copy is stored (what an old client sends)
        assert isinstance(raw_request(service.endpoint, other), wire.OkMsg)
    assert service.sampler.pending_pairs == 3 + 6
    assert service.duplicate_reports == 2


def test_a_bad_state_is_refused_whole_and_changes_nothing(service):
    client = SamplerClient(service.endpoint, timeout_s=5.0)
    try:
        state = client.get_state()
        client.draw(7)  # move the cursor
        baseline = service.sampler.state_dict()
        bad_states = []
        for edit in (
            lambda s: s["meta"].update(cursor=10**9),  # would make draw loop forever
            lambda s: s["meta"].update(generation=-4),
            lambda s: s["meta"].pop("rng"),
            lambda s: s["meta"].update(vm={"hidden": "nope"}),
            lambda s: s["arrays"].update(order=np.zeros(len(s["arrays"]["order"]), np.int64)),
            lambda s: s["arrays"].update(buffer=np.zeros((0, 2))),
        ):
            bad = {"meta": dict(state["meta"]), "arrays": dict(state["arrays"])}
            edit(bad)
            bad_states.append(bad)
        for bad in bad_states:
            with pytest.raises(wire.WireError) as err:
                client.set_state(bad)
            assert err.value.kind == "invalid", err.value
        after = service.sampler.state_dict()
        assert after["meta"] == baseline["meta"]
        for k, v in baseline["arrays"].items():
            np.testing.assert_array_equal(after["arrays"][k], v)
        assert client.draw(3).params.shape == (3, 2)
        assert client.stats()["requests/rejected/invalid"] == len(bad_states)
    finally:
        client.close()


def test_clip_outcomes_travel_with_the_value_report_and_a_bad_one_stores_nothing(service):
    """Adaptive clip sampling over the socket: the report's per-clip segments reach the sampler
    at the tick; a report naming a clip the sampler does not draw, or more tracked segments than
    segments, is refused whole (its value pairs are not stored either) and serving goes on."""
    client = SamplerClient(service.endpoint, timeout_s=5.0)
    try:
        d = client.draw(4)
        with pytest.raises(wire.WireError, match="'no_such_clip': not a clip this sampler draws"):
            client.report(d.params, np.ones(4), (["no_such_clip"], [3], [1]))
        with pytest.raises(wire.WireError, match="5 tracked of 2 segments"):
            client.report(d.params, np.ones(4), ([d.clip_ids[0]], [2], [5]))
        assert client.stats()["vm/pending_pairs"] == 0
        client.report(d.params, np.ones(4), ([d.clip_ids[0]], [4], [1]))
        stats = client.tick(1)
        assert stats["vm/pairs_seen"] == 4 and stats["clips/segments_seen"] == 4
        assert stats["clips/tracked_pct"] == pytest.approx(25.0)
        assert stats["requests/rejected/invalid"] == 2
    finally:
        client.close()


def test_start_times_and_failure_times_over_the_socket():
    """Time bins over real ZeroMQ: draws carry one start per clip inside the clip; a report's
    failure times reach the bins at the tick, a bad one is refused alone (named in the reply and
    counted), a non-finite one is refused by the wire with the whole report; the bins travel in
    the state; a sampler without time bins refuses failure times."""
    clips = [("long", "root/a/x"), ("other", "root/b")]
    durations = {"long": 4.0, "other": 2.0}
    cfg = dataclasses.replace(CFG, time_bin_s=0.5, clip_memory=0.5)
    svc, thread, stop = start_in_thread(cfg, SPACE, clips, durations=durations)
    client = SamplerClient(svc.endpoint, timeout_s=5.0)
    try:
        d = client.draw(40)
        assert len(d.start_s) == 40 and len(d.clip_ids) == 40
        assert all(0.0 <= t <= durations[c] - END_MARGIN_S for c, t in zip(d.clip_ids, d.start_s))
        info = client.report(d.params[:2], np.ones(2), failures=(["long", "long", "other"], [3.2, 9.0, 0.1]))
        assert "stored 2 pairs; refused 1 failure time(s), the first: failure time 9.0 s in clip 'long'" in info
        with pytest.raises(wire.WireError, match="nonfinite|expected a finite float"):
            client.report(d.params[:2], np.ones(2), failures=(["long"], [float("nan")]))
        stats = client.tick(1)
        assert stats["clips/time/fails_seen"] == 2 and stats["clips/time/refused"] == 1
        assert stats["requests/rejected/nonfinite"] == 1 and stats["vm/pairs_seen"] == 2
        assert stats["clips/time/entropy"] < 1.0  # no longer uniform
        more = client.draw(400)
        starts = [t for c, t in zip(more.clip_ids, more.start_s) if c == "long"]
        assert np.mean([1.5 <= t < 3.5 for t in starts]) > 0.8  # before the failure at 3.2 s
        state = client.get_state()
        assert state["meta"]["time_bins"]["bins"] == [8, 4]
        client.set_state(state)
        assert client.stats()["clips/time/fails_seen"] == 2
    finally:
        client.close()
        stop.set()
        thread.join(timeout=5)
    plain, thread, stop = start_in_thread(CFG, SPACE, clips)
    client = SamplerClient(plain.endpoint, timeout_s=5.0)
    try:
        assert client.draw(3).start_s == []  # time bins off: the environment draws the start
        with pytest.raises(wire.WireError, match="keeps no time bins"):
            client.report(np.full((1, 2), 1.0), np.ones(1), failures=(["long"], [1.0]))
    finally:
        client.close()
        stop.set()
        thread.join(timeout=5)
