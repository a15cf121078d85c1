"""The learner's sockets under hostile input, over real ZeroMQ on 127.0.0.1: every bad message
is refused and counted by kind (never raised, never a phantom actor), sequence gaps and stale
unrolls are counted, the weight snapshot service keeps answering, the drain at stop counts what
is still in flight, and a lossy proxy between real actors and the learner shows up as exactly
as many lost unrolls as it dropped."""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import zmq

from common import curve_keys, wire
from learner.presets import PRESETS
from learner.train import Run, train
from learner.transport import LearnerTransport

T, N = 2, 3


def _transport(**kw) -> LearnerTransport:
    args = {"obs_dim": 4, "act_dim": 2, "n_params": 1, "unroll_length": T, "envs_per_actor": N, "num_actors": 2}
    return LearnerTransport("127.0.0.1", **{**args, **kw})


def _unroll(seq: int, version: int = 0, actor_id: int = 1, t: int = T, n: int = N, **kw) -> wire.UnrollMsg:
    z = lambda *s: np.zeros(s, np.float32)
    msg = wire.UnrollMsg(actor_id=actor_id, seq=seq, policy_version=version, obs=z(t, n, 4), next_obs=z(t, n, 4),
                         actions=z(t, n, 2), logp=z(t, n), rewards=z(t, n), terminated=np.zeros((t, n), bool),
                         truncated=np.zeros((t, n), bool), params=z(t, n, 1))
    return dataclasses.replace(msg, **kw)


def _resumed(marks: dict[int, int], gaps: int = 0, **kw) -> LearnerTransport:
    """A transport resumed from a checkpoint whose actors had reached `marks` (and `gaps` lost)."""
    before = _transport(**kw)
    before.last_seq.update(marks)
    before.counters["seq_gap_unrolls"] = gaps
    state = before.state_dict()
    before.close()
    t = _transport(**kw)
    t.load_state_dict(state)
    return t


def _push(t: LearnerTransport) -> zmq.Socket:
    push = zmq.Context.instance().socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 1000)
    push.connect(t.endpoints["unrolls"])
    return push


def _drain(t: LearnerTransport, version: int = 0, lag: int = 1, rounds: int = 40, expect: int | None = None,
           deadline_s: float = 10.0) -> list:
    """What `receive` returns over `rounds` reads of up to 50 ms; with `expect`, reads on until
    that many unrolls came (or `deadline_s` passed): a loaded machine may take longer to connect."""
    out: list = []
    end = time.monotonic() + deadline_s
    for _ in range(rounds):
        out += t.receive(50, version, lag)
    while expect is not None and len(out) < expect and time.monotonic() < end:
        out += t.receive(50, version, lag)
    return out


def _with_header(frames: list[bytes], edit) -> list[bytes]:
    header = msgpack.unpackb(frames[0])
    edit(header)
    return [msgpack.packb(header), *frames[1:]]


def test_hostile_unroll_channel_input_is_counted_by_kind():
    t = _transport()
    push = _push(t)
    try:
        good = [bytes(f) for f in wire.encode(_unroll(0, version=5))]
        push.send_multipart([b"\xff\x00 not msgpack"])
        push.send_multipart(good[:4])  # truncated multipart
        push.send_multipart(_with_header(good, lambda h: h.update(v=9)))
        push.send_multipart(wire.encode(_unroll(1, version=5, rewards=np.full((T, N), np.inf, np.float32))))
        push.send_multipart(wire.encode(_unroll(1, version=5, obs=np.zeros((T, N, 5), np.float32))))
        push.send_multipart(wire.encode(wire.TickMsg(iteration=3)))
        push.send_multipart(good)  # seq 0: fine
        push.send_multipart(wire.encode(_unroll(3, version=5)))  # seq 1 and 2 never arrive
        push.send_multipart(wire.encode(_unroll(4, version=3)))  # too old for lag 1
        push.send_multipart(wire.encode(_unroll(5, version=6)))  # a version the learner never published
        got = _drain(t, version=5)
        c = t.counters
        assert [u.seq for u in got] == [0, 3]
        assert c["rejected/malformed"] == 2 and c["rejected/version"] == 1 and c["rejected/out_of_range"] == 1
        assert c["rejected/nonfinite"] == 1 and c["rejected/bad_shape"] == 1 and c["rejected/unknown_kind"] == 1
        assert c["seq_gap_unrolls"] == 2 and c["stale_unrolls"] == 1
        assert t.received[1] == 3
    finally:
        push.close()
        t.close()


def test_the_wrong_typed_messages_of_issue_22_are_counted_and_the_learner_keeps_receiving():
    """Each of these killed a running learner before: now each is one counted rejection, and
    none creates an actor in the health counters."""
    t = _transport()
    push = _push(t)
    try:
        good = [bytes(f) for f in wire.encode(_unroll(0))]
        heartbeat = [bytes(f) for f in wire.encode(wire.HeartbeatMsg(actor_id=0, seq=-1, env_steps=0))]

        def dtype_as_list(h):
            h["a"][0][1] = ["<f4"]

        cases = [
            ("bad_type", _with_header(heartbeat, lambda h: h["f"].update(actor_id=[1, 2]))),
            ("bad_array", _with_header(good, dtype_as_list)),
            ("bad_shape", [bytes(f) for f in wire.encode(_unroll(0, t=T + 3))]),  # self-consistent, wrong T
            ("bad_shape", [bytes(f) for f in wire.encode(_unroll(0, n=N + 1))]),  # wrong N
            ("bad_type", _with_header(good, lambda h: h["f"].update(seq="7"))),
            ("bad_type", _with_header(good, lambda h: h["f"].update(seq=True))),  # a bool is not an int
            ("out_of_range", _with_header(good, lambda h: h["f"].update(seq=2**63))),
            ("unknown_actor", [bytes(f) for f in wire.encode(_unroll(0, actor_id=2))]),
            ("unknown_actor", [bytes(f) for f in wire.encode(wire.HeartbeatMsg(actor_id=77, seq=0, env_steps=1))]),
            ("bad_array", _with_header(good, lambda h: h["a"].append(["extra", "<f4", [0]])) + [b""]),
            ("bad_type", _with_header(good, lambda h: h["f"].update(episode_returns={"a": 1}))),
            ("nonfinite", _with_header(good, lambda h: h["f"].update(episode_returns=[float("nan")],
                                                                      episode_lengths=[3]))),
            ("bad_shape", _with_header(good, lambda h: h["f"].update(episode_returns=[1.0], episode_lengths=[]))),
        ]
        for _, frames in cases:
            push.send_multipart(frames)
        push.send_multipart(good)
        got = _drain(t)
        expected: dict[str, int] = {}
        for kind, _ in cases:
            expected[f"rejected/{kind}"] = expected.get(f"rejected/{kind}", 0) + 1
        assert {k: v for k, v in t.counters.items() if k.startswith("rejected/")} == expected
        assert t.rejected() == len(cases)
        assert [u.seq for u in got] == [0]
        assert set(t.last_seen) == {1} and set(t.last_seq) == {1}  # no phantom actors 2, 77
    finally:
        push.close()
        t.close()


def test_an_internal_error_while_accepting_is_counted_not_raised(monkeypatch):
    t = _transport()
    push = _push(t)
    try:
        calls = []

        def broken(*a, **kw):
            calls.append(1)
            raise KeyError("a bug of ours")

        monkeypatch.setattr(t, "_book", broken)
        push.send_multipart(wire.encode(_unroll(0)))
        assert _drain(t, rounds=10) == []
        assert calls and t.counters["rejected/internal"] == 1
        monkeypatch.undo()
        push.send_multipart(wire.encode(_unroll(1)))
        assert [u.seq for u in _drain(t, rounds=10, expect=1)] == [1]
    finally:
        push.close()
        t.close()


def test_a_resumed_learner_counts_what_the_killed_session_took_after_its_checkpoint_as_lost_at_resume():
    """The checkpoint was written when actor 1 had sent seq 10; the session took 11-19 and was
    killed; the actor's ledger numbers on from 20. Those 9 are work lost with the session
    (`lost/unrolls_at_resume`), not wire gaps; only a gap after the new baseline is one. Actor
    0, absent from the checkpoint, sets its baseline and books nothing."""
    t = _resumed({1: 10}, gaps=3)
    push = _push(t)
    try:
        push.send_multipart(wire.encode(wire.HeartbeatMsg(actor_id=0, seq=40, env_steps=1)))  # baseline, no gap
        for seq in (20, 21, 23):
            push.send_multipart(wire.encode(_unroll(seq)))
        push.send_multipart(wire.encode(_unroll(42, actor_id=0)))  # 41 lost
        assert [u.seq for u in _drain(t, expect=4)] == [20, 21, 23, 42]
        assert t.counters["seq_gap_unrolls"] == 3 + 1 + 1  # seq 22 of actor 1, 41 of actor 0
        assert t.counters["lost/unrolls_at_resume"] == 9  # 11-19 of actor 1
    finally:
        push.close()
        t.close()


def test_after_a_resume_a_spoofed_low_number_or_an_implausible_jump_books_nothing():
    """After a clean stop the checkpoint holds each actor's last number: the next one follows on
    and nothing is booked. A spoofed seq 0 arriving before an actor's first real message cannot
    set a low baseline (the checkpoint's mark is the high-water mark), so the real numbers that
    follow book only what the killed session took (here 11-19), no phantom gap. A first number
    past the mark by more than the killed session could have numbered is refused, and the
    unroll after it, following on, is taken without booking the jump."""
    t = _resumed({0: 7, 1: 10, 2: 5}, num_actors=3)
    t.resume_allowance = 50
    push = _push(t)
    try:
        push.send_multipart(wire.encode(_unroll(8, actor_id=0)))
        push.send_multipart(wire.encode(_unroll(0, actor_id=1)))  # the spoof, first
        push.send_multipart(wire.encode(_unroll(20, actor_id=1)))
        push.send_multipart(wire.encode(_unroll(10_000, actor_id=2)))
        push.send_multipart(wire.encode(_unroll(10_001, actor_id=2)))
        assert [u.seq for u in _drain(t, expect=4)] == [8, 0, 20, 10_001]
        assert t.counters["lost/unrolls_at_resume"] == 9 and t.counters["seq_gap_unrolls"] == 0
        assert t.counters["rejected/seq_jump"] == 1 and t.counters["seq_restarts"] == 1
    finally:
        push.close()
        t.close()


def test_an_unroll_that_arrives_after_a_later_number_is_taken_back_from_the_gaps():
    """A restarted actor's new connection can be read before the unroll its killed process left
    on the old one (the PULL socket takes turns between connections; CI saw seq 27 before 26).
    The gap booked when 27 came first is taken back when 26 arrives: counted as `late_unrolls`,
    received once, no sequence restart, and the high-water mark stays where it was."""
    t = _transport()
    old, new = _push(t), _push(t)
    try:
        for seq in (0, 1):
            old.send_multipart(wire.encode(_unroll(seq)))
        assert [u.seq for u in _drain(t, rounds=5, expect=2)] == [0, 1]
        new.send_multipart(wire.encode(_unroll(3)))  # the restarted process, first
        assert [u.seq for u in _drain(t, rounds=5, expect=1)] == [3]
        assert t.lost() == 1
        old.send_multipart(wire.encode(_unroll(2)))  # the killed process's last unroll, late
        new.send_multipart(wire.encode(_unroll(4)))
        assert sorted(u.seq for u in _drain(t, rounds=5, expect=2)) == [2, 4]
        assert t.lost() == 0 and t.counters["late_unrolls"] == 1 and t.counters["seq_restarts"] == 0
        assert t.received[1] == 5 and t.last_seq[1] == 4
        old.send_multipart(wire.encode(_unroll(2)))  # the same number again is no second late arrival
        assert len(_drain(t, rounds=5, expect=1)) == 1  # a restart of the numbering, not a late arrival
        assert t.lost() == 0 and t.counters["late_unrolls"] == 1 and t.last_seq[1] == 4
    finally:
        old.close()
        new.close()
        t.close()


def test_a_restarted_numbering_forgets_the_old_gaps_and_a_late_unroll_after_a_resume_is_taken_back():
    """Actor 0 lost seq 2, then restarted its numbering from 0 (no ledger): its new seq 2 is a
    new unroll, not the old one arriving late, so the gap stays. After a resume (actor 1's mark
    20), 27 coming first books 21-26 as lost with the killed session; 26 arriving after it is
    taken back from `lost/unrolls_at_resume`."""
    t = _resumed({1: 20})
    push = _push(t)
    try:
        for seq in (0, 1, 3, 0, 1, 2):
            push.send_multipart(wire.encode(_unroll(seq, actor_id=0)))
        push.send_multipart(wire.encode(_unroll(27)))
        push.send_multipart(wire.encode(_unroll(26)))
        assert len(_drain(t, rounds=10, expect=8)) == 8
        assert t.lost() == 1 and t.counters["seq_restarts"] == 1
        assert t.counters["lost/unrolls_at_resume"] == 5 and t.counters["late_unrolls"] == 1
        assert t.last_seq == {0: 3, 1: 27}
    finally:
        push.close()
        t.close()


def test_heartbeats_expose_lost_unrolls_and_drain_at_stop_counts_what_arrives():
    """A heartbeat follows the unrolls on their pipe: numbers up to its seq that did not arrive
    are lost. At stop, `drain` reads until each actor's final heartbeat: what arrives then is
    counted, and a final seq past the last unroll received counts the tail as lost."""
    t = _transport()
    push = _push(t)
    try:
        for seq in (0, 1, 2):
            push.send_multipart(wire.encode(_unroll(seq, actor_id=0)))
        push.send_multipart(wire.encode(wire.HeartbeatMsg(actor_id=0, seq=4, env_steps=10)))  # 3, 4 lost
        push.send_multipart(wire.encode(wire.HeartbeatMsg(actor_id=1, seq=-1, env_steps=0)))  # nothing sent yet
        assert len(_drain(t, rounds=10, expect=3)) == 3
        assert t.lost() == 2 and t.last_seq == {0: 4}
        # Stop: actor 0 sends two more unrolls and its final word; actor 1 numbered 0..2, sent only 0.
        push.send_multipart(wire.encode(_unroll(5, actor_id=0)))
        push.send_multipart(wire.encode(_unroll(6, actor_id=0)))
        push.send_multipart(wire.encode(wire.HeartbeatMsg(actor_id=0, seq=6, env_steps=20, final=True)))
        push.send_multipart(wire.encode(_unroll(0, actor_id=1)))
        push.send_multipart(wire.encode(wire.HeartbeatMsg(actor_id=1, seq=2, env_steps=20, final=True)))
        assert t.drain(0, 1, {0, 1}, quiet_s=5.0, max_s=10.0) == 3
        assert t.finals == {0: 6, 1: 2}
        assert t.lost() == 2 + 2
        assert t.counters["drained_at_stop"] == 3 and t.counters["unused_at_stop"] == 3
        numbered = 7 + 3
        assert sum(t.received.values()) + t.lost() == numbered  # nothing left "in flight"
        # An actor that never says its final word costs the quiet period, not a hang.
        assert t.drain(0, 1, {0, 1, 5}, quiet_s=0.3, max_s=5.0) == 0
    finally:
        push.close()
        t.close()


def test_snapshot_service_answers_garbage_with_errors_and_serves_weights():
    t = _transport()
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
        assert ask(wire.encode(wire.WeightsRequestMsg(actor_id=9))).error_kind == "unknown_actor"
        t.publish(wire.WeightsMsg(policy_version=4, tensors={"w": np.ones(3, np.float32)}))
        reply = ask(wire.encode(wire.WeightsRequestMsg(actor_id=0)))
        assert isinstance(reply, wire.WeightsMsg) and reply.policy_version == 4
        assert t.snapshots.rejected == {"malformed": 1, "unknown_actor": 1}
    finally:
        dealer.close()
        t.close()


# --------------------------------------------------------------------------------------------
# A lossy proxy between real rollout actors and the learner.


class LossyProxy:
    """PULL (actors connect here) -> PUSH (to the learner's PULL), on 127.0.0.1, dropping every
    `every`-th unroll; heartbeats and everything else pass. With the run's CURVE keys it is a
    member on both sides (a server to the actors; to the learner, each actor under its own key,
    the only one the learner takes that actor's messages under)."""

    def __init__(self, learner_endpoint: str, every: int, keys=None):
        self.every = every
        self.drop_next = 0
        """Drop this many unrolls from now on, whatever their place in the pattern."""
        self.unrolls = self.dropped = self.forwarded = 0
        self.dropped_seqs: list[tuple[int, int]] = []
        ctx = zmq.Context.instance()
        self.front = ctx.socket(zmq.PULL)
        curve_keys.make_server(self.front, keys)
        self.front.setsockopt(zmq.LINGER, 0)
        port = self.front.bind_to_random_port("tcp://127.0.0.1")
        self.endpoint = f"tcp://127.0.0.1:{port}"
        self.keys, self.learner_endpoint = keys, learner_endpoint
        self.backs: dict[int, zmq.Socket] = {}
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="lossy-proxy", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            if not self.front.poll(20, zmq.POLLIN):
                continue
            frames = self.front.recv_multipart()
            header = msgpack.unpackb(frames[0])
            if header["k"] == "unroll":
                self.unrolls += 1
                if self.unrolls % self.every == 0 or self.drop_next > 0:
                    self.drop_next = max(0, self.drop_next - 1)
                    self.dropped += 1
                    self.dropped_seqs.append((header["f"]["actor_id"], header["f"]["seq"]))
                    continue
            self._back(header["f"]["actor_id"]).send_multipart(frames)
            self.forwarded += 1

    def _back(self, actor_id: int) -> zmq.Socket:
        if actor_id not in self.backs:
            sock = zmq.Context.instance().socket(zmq.PUSH)
            curve_keys.make_client(sock, self.keys.for_actor(actor_id) if self.keys is not None else None, curve_keys.ACTOR)
            sock.setsockopt(zmq.LINGER, 2000)
            sock.connect(self.learner_endpoint)
            self.backs[actor_id] = sock
        return self.backs[actor_id]

    def close(self) -> None:
        self._stop.set()
        self.thread.join(timeout=10)
        self.front.close()
        for sock in self.backs.values():
            sock.close()


def _ledger_total(run_dir: Path) -> dict[int, int]:
    return {int(p.stem.split("-")[1]): int(p.read_text().strip("\0 \n")) + 1 for p in (run_dir / "ledger").glob("actor-*.seq")}


def test_a_lossy_proxy_between_actors_and_learner_raises_the_lost_count_by_exactly_the_drops(tmp_path, monkeypatch):
    """A real serial run (two real rollout actors, ledgers on) with a proxy that drops every 3rd
    unroll in flight. After the last iteration each actor sends one unroll that passes (drained
    at stop) and then one that the proxy drops: no later unroll can reveal that one, only the
    actor's final heartbeat. The learner's lost count equals the number dropped, and for every
    actor ledger = received + lost, with nothing left "in flight"."""
    proxies: list[LossyProxy] = []
    real_init = LearnerTransport.__init__

    def init(self, *args, **kw):
        real_init(self, *args, **kw)
        proxies.append(LossyProxy(self.endpoints["unrolls"], every=3, keys=kw.get("keys")))
        self.endpoints = {**self.endpoints, "unrolls": proxies[-1].endpoint}

    monkeypatch.setattr(LearnerTransport, "__init__", init)
    cfg = dataclasses.replace(PRESETS["reach-tiny"][1], runs_dir=str(tmp_path), quiet=True, mode="serial",
                              max_iterations=3, total_env_steps=10**6, checkpoint_every=100, vm_plot_every=0)
    seen: dict = {}

    def hook(run: Run, metrics: dict) -> None:
        seen["run"] = run
        if run.learner.iteration == cfg.max_iterations:  # the loop ends after this hook
            proxy = proxies[0]
            proxy.drop_next = 0
            before = proxy.unrolls
            run.pool.pump()  # one unroll per actor that gets through: drained at stop
            for _ in range(200):
                if proxy.unrolls == before + 2:
                    break
                threading.Event().wait(0.01)
            proxy.drop_next = 2  # NOTE: set after the previous two passed, so it cannot catch them
            run.pool.pump()  # the last unroll of each actor: dropped

    try:
        assert train(cfg, on_iteration=hook) == 0
    finally:
        for p in proxies:
            p.close()
    proxy, t = proxies[0], seen["run"].transport
    sent = _ledger_total(seen["run"].run_dir)
    print(f"\nlossy proxy: {proxy.unrolls} unrolls through it, {proxy.dropped} dropped {proxy.dropped_seqs}; "
          f"learner: received {sum(t.received.values())}, lost {t.lost()}, finals {t.finals}, "
          f"drained {t.counters['drained_at_stop']}; ledgers {sent}")
    assert proxy.dropped >= 5
    assert t.lost() == proxy.dropped
    assert t.finals.keys() == {0, 1}
    assert {(a, t.finals[a]) for a in (0, 1)} <= set(proxy.dropped_seqs)  # the tails were dropped
    assert t.counters["drained_at_stop"] >= 1
    assert sum(sent.values()) == proxy.unrolls == sum(t.received.values()) + t.lost()
    assert t.rejected() == 0 and t.counters["seq_restarts"] == 0
    log = (tmp_path / "reach-tiny" / "log.txt").read_text()
    assert f"lost unrolls (sequence gaps) {proxy.dropped}" in log
