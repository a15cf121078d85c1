"""Property-based fuzzing of the wire (issue 22, item 1): random and mutated messages thrown at
`wire.decode` in process and at the learner's and the sampler's receive paths over real ZeroMQ
sockets on 127.0.0.1.

Mutations start from valid encoded messages of every kind: bytes flipped, header fields given
another type (list, str, dict, nested, huge int, NaN, bool, None), fields removed or added, the
header's kind/version/protocol changed, array specs given other dtypes, shapes and names,
frames dropped, duplicated, swapped or added, T and N changed (self-consistently), NaN written
into arrays, the header cut short; plus frames of random bytes.

Asserted: `decode` raises nothing but `WireError` (with a known kind); the services stay up,
count every rejection exactly (a rejection counter rises by exactly the number of messages
the contract refuses) and still answer a valid request afterwards. Reproducible:
`derandomize=True`, no example database.
"""

from __future__ import annotations

import collections
import time

import msgpack
import numpy as np
import pytest
import zmq
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common import sockets, wire
from common.params import ParamSpace
from learner.transport import LearnerTransport
from sampler.actor import start_in_thread
from sampler.client import SamplerClient
from sampler.config import SamplerConfig
from sampler.shape_sampler import ShapeSampler

THROWN: collections.Counter[str] = collections.Counter()
"""Messages thrown per path (printed at the end of the module with `-s`)."""
REJECTED: collections.Counter[str] = collections.Counter()

DECODE_EXAMPLES = 6500
RAW_EXAMPLES = 500
LEARNER_BATCHES, LEARNER_BATCH = 100, 20
ROUTER_BATCHES, ROUTER_BATCH = 20, 15
SAMPLER_BATCHES, SAMPLER_BATCH = 100, 15


def _settings(n: int):
    return settings(max_examples=n, deadline=None, derandomize=True, database=None,
                    suppress_health_check=list(HealthCheck))


# --------------------------------------------------------------------------------------------
# Valid messages to start from.

T, N, OBS, ACT, NP = 2, 3, 4, 2, 1
NUM_ACTORS = 2
LEARNER_DIMS = {"T": T, "N": N, "obs_dim": OBS, "act_dim": ACT, "n_params": NP}
SPACE = ParamSpace(names=("leg", "arm"), low=(0.5, 0.5), high=(2.0, 1.5))
CFG = SamplerConfig(p_mcmc=2, n_mcmc=200, n_chains=16, burn_in=20, vm_fit_steps=5, probe_points=64, seed=3,
                    vm_hidden=(16, 16), max_draw=64)


def _unroll(t: int = T, n: int = N, actor_id: int = 1, seq: int = 0, version: int = 3, n_params: int = NP) -> wire.UnrollMsg:
    rng = np.random.default_rng(seq)
    f = lambda *s: rng.normal(size=s).astype(np.float32)
    return wire.UnrollMsg(
        actor_id=actor_id, seq=seq, policy_version=version, obs=f(t, n, OBS), next_obs=f(t, n, OBS),
        actions=f(t, n, ACT), logp=f(t, n), rewards=f(t, n), terminated=rng.random((t, n)) < 0.3,
        truncated=rng.random((t, n)) < 0.3, params=f(t, n, n_params),
        episode_returns=[1.5, -2.0], episode_lengths=[3, 7], divergences=1, sampler_outages=2,
    )


def _frames(msg) -> list[bytes]:
    return [bytes(f) for f in wire.encode(msg)]


_state = ShapeSampler(CFG, SPACE).state_dict()
STATE = wire.StateMsg(meta=_state["meta"], arrays=_state["arrays"])

ALL_KINDS = [
    _unroll(),
    wire.WeightsMsg(policy_version=4, tensors={"a.weight": np.ones((3, 2), np.float32), "count": np.array(5.0)}),
    wire.WeightsRequestMsg(actor_id=1, have_version=-1),
    wire.HeartbeatMsg(actor_id=1, seq=9, env_steps=100),
    wire.HeartbeatMsg(actor_id=0, seq=3, env_steps=100, final=True),
    wire.DrawRequestMsg(n=4, client_id=3),
    wire.DrawReplyMsg(params=np.zeros((2, 3), np.float32), clip_ids=["walk", "run"], buffer_generation=4),
    wire.ValueReportMsg(params=np.full((5, 2), 1.0, np.float32), values=np.arange(5, dtype=np.float32), report_id="x-1"),
    wire.TickMsg(iteration=12),
    wire.StatsRequestMsg(),
    wire.StatsReplyMsg(stats={"vm/min": 1.0, "vm/fit_loss": float("nan")}),
    wire.StateRequestMsg(),
    STATE,
    wire.OkMsg(info="fine"),
    wire.ErrorMsg(reason="bad", error_kind="malformed"),
]
assert {type(m).KIND for m in ALL_KINDS} == set(wire.MESSAGES)

DECODE_POOL = [_frames(m) for m in ALL_KINDS]
LEARNER_POOL = [_frames(m) for m in (
    _unroll(), _unroll(actor_id=0, seq=5), _unroll(t=1, n=1),
    wire.HeartbeatMsg(actor_id=0, seq=2, env_steps=10), wire.HeartbeatMsg(actor_id=1, seq=-1, env_steps=0, final=True),
    wire.TickMsg(iteration=1),
)]
ROUTER_POOL = [_frames(m) for m in (wire.WeightsRequestMsg(actor_id=1), wire.WeightsRequestMsg(actor_id=0, have_version=3),
                                    wire.StatsRequestMsg())]
SAMPLER_POOL = [_frames(m) for m in (
    wire.DrawRequestMsg(n=4), wire.DrawRequestMsg(n=1, client_id=2),
    wire.ValueReportMsg(params=np.full((5, 2), 1.0, np.float32), values=np.arange(5, dtype=np.float32), report_id="r-1"),
    wire.ValueReportMsg(params=np.full((2, 2), 0.7, np.float32), values=np.ones(2, np.float32)),
    wire.TickMsg(iteration=3), wire.StatsRequestMsg(), wire.StateRequestMsg(), STATE, wire.OkMsg(info="x"),
)]


# --------------------------------------------------------------------------------------------
# Mutations: each takes hypothesis' `draw` and a valid message's frames, returns new frames.

KINDS = sorted(wire.MESSAGES)
HOSTILE = st.one_of(
    st.none(), st.booleans(),
    st.sampled_from([2**63, 2**64 - 1, -(2**63), 2**53 + 1, -1, 0, 1, 10**12]),
    st.integers(min_value=-(2**63), max_value=2**64 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([float("nan"), float("inf"), -float("inf"), 1e308]),
    st.text(max_size=6), st.binary(max_size=4),
    st.lists(st.integers(-3, 3), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(-2, 2), max_size=2),
    st.recursive(st.integers(0, 3), lambda c: st.lists(c, max_size=2) | st.dictionaries(st.text(max_size=2), c, max_size=2),
                 max_leaves=6),
)


def _header(frames: list[bytes]) -> dict:
    return msgpack.unpackb(frames[0])


def _pack(header: dict, frames: list[bytes]) -> list[bytes]:
    return [msgpack.packb(header, use_bin_type=True), *frames[1:]]


def m_none(draw, frames):
    return frames


def m_flip_bytes(draw, frames):
    i = draw(st.integers(0, len(frames) - 1))
    data = bytearray(frames[i])
    if not data:
        return frames
    for _ in range(draw(st.integers(1, 4))):
        pos = draw(st.integers(0, len(data) - 1))
        data[pos] ^= draw(st.integers(1, 255))
    return [*frames[:i], bytes(data), *frames[i + 1:]]


def m_field_type(draw, frames):
    h = _header(frames)
    f = h["f"]
    if f and draw(st.booleans()):
        key = draw(st.sampled_from(sorted(f)))
        f[key] = draw(HOSTILE)
    else:
        f[draw(st.text(min_size=1, max_size=8))] = draw(HOSTILE)
    return _pack(h, frames)


def m_field_remove(draw, frames):
    h = _header(frames)
    if h["f"]:
        del h["f"][draw(st.sampled_from(sorted(h["f"])))]
    return _pack(h, frames)


def m_deep(draw, frames):
    h = _header(frames)
    deep: object = 1
    for _ in range(draw(st.sampled_from([20, 500, 1000]))):  # msgpack itself stops at 1024
        deep = [deep]
    key = draw(st.sampled_from(sorted(h["f"]) or ["x"]))
    h["f"][key] = deep if draw(st.booleans()) else {"k": deep}
    return _pack(h, frames)


def m_top(draw, frames):
    h = _header(frames)
    what = draw(st.sampled_from(["k", "v", "p", "f", "a", "extra", "drop", "not_a_map"]))
    if what == "k":
        h["k"] = draw(st.one_of(st.sampled_from(KINDS), HOSTILE))
    elif what == "v":
        h["v"] = draw(st.one_of(st.sampled_from([1, 2, 3, True]), HOSTILE))
    elif what == "p":
        h["p"] = draw(st.one_of(st.just("morphmimic/2"), HOSTILE))
    elif what in ("f", "a"):
        h[what] = draw(HOSTILE)
    elif what == "extra":
        h[draw(st.text(min_size=1, max_size=3))] = draw(HOSTILE)
    elif what == "drop":
        del h[draw(st.sampled_from(sorted(h)))]
    else:
        return [msgpack.packb(draw(HOSTILE), use_bin_type=True), *frames[1:]]
    return _pack(h, frames)


def m_spec(draw, frames):
    h = _header(frames)
    if not h["a"]:
        h["a"].append(["x", "<f4", [0]])
        return _pack(h, frames) + [b""]
    i = draw(st.integers(0, len(h["a"]) - 1))
    spec = h["a"][i]
    what = draw(st.sampled_from(["dtype", "shape_swap", "shape_edit", "shape_add", "name", "spec"]))
    if what == "dtype":
        spec[1] = draw(st.one_of(st.sampled_from([*sorted(wire.ALLOWED_DTYPES), "|O", "<c8", ">f4", "V8"]),
                                 st.just(["<f4"]), HOSTILE))
    elif what == "shape_swap" and len(spec[2]) >= 2:
        spec[2] = list(reversed(spec[2]))  # same byte count, other shape
    elif what == "shape_edit" and spec[2]:
        j = draw(st.integers(0, len(spec[2]) - 1))
        spec[2][j] = draw(st.one_of(st.sampled_from([-1, 0, 2**40, 2**62, True]), HOSTILE))
    elif what == "shape_add":
        spec[2] = [*spec[2], draw(st.sampled_from([1, 0, 2, 2**31]))]
    elif what == "name":
        spec[0] = draw(st.one_of(st.sampled_from([s[0] for s in h["a"]] + ["", "obs/x", "tensors/"]), HOSTILE))
    else:
        h["a"][i] = draw(HOSTILE)
    return _pack(h, frames)


def m_frames(draw, frames):
    what = draw(st.sampled_from(["drop", "dup", "add", "swap", "empty", "header_only"]))
    frames = list(frames)
    if what == "drop":
        del frames[draw(st.integers(0, len(frames) - 1))]
    elif what == "dup":
        i = draw(st.integers(0, len(frames) - 1))
        frames.insert(i, frames[i])
    elif what == "add":
        frames.insert(draw(st.integers(0, len(frames))), draw(st.binary(max_size=32)))
    elif what == "swap" and len(frames) > 2:
        i, j = draw(st.integers(1, len(frames) - 1)), draw(st.integers(1, len(frames) - 1))
        frames[i], frames[j] = frames[j], frames[i]
    elif what == "empty":
        frames = []
    else:
        frames = frames[:1]
    return frames


def m_nonfinite(draw, frames):
    h = _header(frames)
    floats = [i for i, s in enumerate(h["a"]) if s[1] in ("<f4", "<f8") and len(frames[i + 1])]
    if not floats:
        return frames
    i = draw(st.sampled_from(floats))
    dtype = np.dtype(h["a"][i][1])
    arr = np.frombuffer(frames[i + 1], dtype).copy()
    arr[draw(st.integers(0, arr.size - 1))] = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    return [*frames[:i + 1], arr.tobytes(), *frames[i + 2:]]


def m_dims(draw, frames):
    """A self-consistent message of other sizes: T, N or n_params changed throughout."""
    kind = _header(frames)["k"]
    if kind == "unroll":
        t, n = draw(st.integers(0, 4)), draw(st.integers(0, 4))
        return _frames(_unroll(t=t, n=n, n_params=draw(st.sampled_from([NP, NP, 2]))))
    if kind == "value_report":
        m, d = draw(st.integers(0, 4)), draw(st.integers(1, 3))
        return _frames(wire.ValueReportMsg(params=np.ones((m, d), np.float32), values=np.ones(m, np.float32)))
    return frames


def m_truncate(draw, frames):
    cut = draw(st.integers(0, max(0, len(frames[0]) - 1)))
    return [frames[0][:cut], *frames[1:]]


def m_random(draw, frames):
    return draw(st.lists(st.binary(max_size=48), min_size=1, max_size=4))


MUTATIONS = [m_none, m_flip_bytes, m_field_type, m_field_type, m_field_remove, m_deep, m_top, m_spec, m_spec,
             m_frames, m_nonfinite, m_dims, m_truncate, m_random]


@st.composite
def mutated(draw, pool: list[list[bytes]], min_frames: int = 0) -> list[bytes]:
    base = draw(st.sampled_from(pool))
    for _ in range(draw(st.sampled_from([1, 1, 1, 2]))):  # sometimes two mutations
        try:
            base = draw(st.sampled_from(MUTATIONS))(draw, base)
        except (ValueError, TypeError, KeyError, IndexError, AttributeError):
            pass  # a header mutation of an already mangled header: keep it as it is
        if not base:
            break
    return base if len(base) >= min_frames else [b""]


# --------------------------------------------------------------------------------------------
# What the contract refuses (the oracles the services are held to).


def learner_refuses(frames: list[bytes], policy_version: int) -> bool:
    try:
        msg = wire.decode(frames, expect=(wire.UnrollMsg, wire.HeartbeatMsg), dims=LEARNER_DIMS)
    except wire.WireError:
        return True
    if msg.actor_id >= NUM_ACTORS:
        return True
    return isinstance(msg, wire.UnrollMsg) and msg.policy_version > policy_version


def decode_refusal(frames: list[bytes], dims: dict | None = None) -> str | None:
    """The kind `decode` (+ the services' check_finite) refuses these frames with, or None."""
    try:
        wire.check_finite(wire.decode(frames, dims=dims))
    except wire.WireError as exc:
        return exc.kind
    return None


@pytest.fixture(scope="module", autouse=True)
def _summary():
    t0 = time.monotonic()
    yield
    print(f"\n[wire fuzz] thrown {dict(THROWN)} total {sum(THROWN.values())}; "
          f"rejected {dict(REJECTED)} total {sum(REJECTED.values())}; {time.monotonic() - t0:.1f} s")


# --------------------------------------------------------------------------------------------
# decode, in process


@_settings(DECODE_EXAMPLES)
@given(frames=mutated(DECODE_POOL), use_dims=st.booleans())
def test_decode_raises_only_wire_error(frames, use_dims):
    THROWN["decode"] += 1
    try:
        msg = wire.decode(frames, dims=LEARNER_DIMS if use_dims else None)
    except wire.WireError as exc:
        REJECTED["decode"] += 1
        assert exc.kind in wire.ERROR_KINDS, exc.kind
        return
    assert type(msg) in wire.MESSAGES.values()
    back = wire.decode(_frames(msg))  # what decodes re-encodes to itself
    assert type(back) is type(msg)


@_settings(RAW_EXAMPLES)
@given(frames=st.one_of(
    st.lists(st.binary(max_size=64), max_size=4),
    st.lists(st.one_of(st.integers(), st.text(max_size=4), st.none()), max_size=3),
    st.binary(max_size=16), st.integers(), st.none(), st.text(max_size=8),
))
def test_decode_of_any_input_raises_only_wire_error(frames):
    THROWN["decode_raw"] += 1
    try:
        wire.decode(frames)
    except wire.WireError as exc:
        REJECTED["decode_raw"] += 1
        assert exc.kind in wire.ERROR_KINDS


# --------------------------------------------------------------------------------------------
# The learner's receive paths over real sockets


VERSION, LAG = 50, 10**9


def _processed(t: LearnerTransport) -> int:
    return t.rejected() + t.counters["heartbeats"] + t.counters["unrolls_received"]


def test_learner_unroll_socket_counts_every_refusal_and_keeps_receiving():
    t = LearnerTransport("127.0.0.1", OBS, ACT, NP, unroll_length=T, envs_per_actor=N, num_actors=NUM_ACTORS)
    push = zmq.Context.instance().socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    push.connect(t.endpoints["unrolls"])
    try:
        @_settings(LEARNER_BATCHES)
        @given(batch=st.lists(mutated(LEARNER_POOL, min_frames=1), min_size=LEARNER_BATCH, max_size=LEARNER_BATCH))
        def throw(batch):
            refused = sum(learner_refuses(frames, VERSION) for frames in batch)
            before, rejected_before, jumps_before = _processed(t), t.rejected(), t.counters["rejected/seq_jump"]
            for frames in batch:
                push.send_multipart(frames)
            deadline = time.monotonic() + 20
            while _processed(t) - before < len(batch) and time.monotonic() < deadline:
                t.receive(20, VERSION, LAG)
            assert _processed(t) - before == len(batch)
            # NOTE: a number too far past the actor's last is refused by what the learner saw
            # before (tests/learner/test_forged_counters.py), not by the message alone.
            assert t.rejected() - rejected_before == refused + t.counters["rejected/seq_jump"] - jumps_before
            THROWN["learner_unrolls"] += len(batch)
            REJECTED["learner_unrolls"] += refused

        throw()
        assert t.counters["rejected/internal"] == 0
        assert set(t.last_seen) <= set(range(NUM_ACTORS))  # no phantom actors
        # Still up: a valid unroll goes through.
        seq = t.last_seq.get(0, -1) + 1
        push.send_multipart(_frames(_unroll(actor_id=0, seq=seq, version=VERSION)))
        got = []
        for _ in range(100):
            got += t.receive(20, VERSION, LAG)
            if got:
                break
        assert [u.seq for u in got] == [seq]
    finally:
        push.close()
        t.close()


def test_learner_weights_router_answers_and_counts_every_refusal():
    t = LearnerTransport("127.0.0.1", OBS, ACT, NP, unroll_length=T, envs_per_actor=N, num_actors=NUM_ACTORS)
    t.publish(wire.WeightsMsg(policy_version=VERSION, tensors={"w": np.ones(3, np.float32)}))
    dealer = sockets.connect_dealer(t.endpoints["weights_router"])

    def ask(frames):
        dealer.send_multipart([b"", *frames])
        for _ in range(500):
            t.receive(10, VERSION, LAG)
            if dealer.poll(0):
                return wire.decode(dealer.recv_multipart()[1:])
        raise AssertionError("the weights service did not answer")

    try:
        @_settings(ROUTER_BATCHES)
        @given(batch=st.lists(mutated(ROUTER_POOL, min_frames=1), min_size=ROUTER_BATCH, max_size=ROUTER_BATCH))
        def throw(batch):
            before = sum(t.snapshots.rejected.values())
            errors = 0
            for frames in batch:
                reply = ask(frames)
                refusal = decode_refusal(frames)
                if isinstance(reply, wire.ErrorMsg):
                    errors += 1
                    assert refusal is None or reply.error_kind == refusal
                else:
                    assert refusal is None and isinstance(reply, wire.WeightsMsg)
            assert sum(t.snapshots.rejected.values()) - before == errors
            THROWN["learner_weights_router"] += len(batch)
            REJECTED["learner_weights_router"] += errors

        throw()
        assert t.snapshots.rejected["internal"] == 0
        assert isinstance(ask(_frames(wire.WeightsRequestMsg(actor_id=0))), wire.WeightsMsg)
    finally:
        dealer.close(linger=0)
        t.close()


# --------------------------------------------------------------------------------------------
# The sampler's receive path over a real socket


def test_sampler_service_answers_every_message_and_counts_every_refusal():
    service, thread, stop = start_in_thread(CFG, SPACE)
    dealer = sockets.connect_dealer(service.endpoint)
    dims = {"n_params": SPACE.dim}
    try:
        @_settings(SAMPLER_BATCHES)
        @given(batch=st.lists(mutated(SAMPLER_POOL, min_frames=1), min_size=SAMPLER_BATCH, max_size=SAMPLER_BATCH))
        def throw(batch):
            before = sum(service.server.rejected.values())
            errors = 0
            for frames in batch:
                dealer.send_multipart([b"", *frames])
                assert dealer.poll(20_000, zmq.POLLIN), "the sampler stopped answering"
                reply = wire.decode(dealer.recv_multipart()[1:])
                refusal = decode_refusal(frames, dims)
                if isinstance(reply, wire.ErrorMsg):
                    errors += 1
                    assert refusal is None or reply.error_kind == refusal, (refusal, reply)
                else:
                    assert refusal is None, (refusal, reply)
            assert sum(service.server.rejected.values()) - before == errors
            THROWN["sampler"] += len(batch)
            REJECTED["sampler"] += errors

        throw()
        assert thread.is_alive()
        client = SamplerClient(service.endpoint, timeout_s=10.0)
        try:
            assert client.draw(3).params.shape == (3, 2)
            stats = client.stats()
            assert stats["requests/rejected"] == sum(service.server.rejected.values())
            print(f"\n[wire fuzz] sampler refusals by kind: {dict(service.server.rejected)}")
        finally:
            client.close()
    finally:
        dealer.close(linger=0)
        stop.set()
        thread.join(timeout=10)
