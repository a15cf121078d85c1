"""The wire codec: every message round-trips; garbage, truncation, wrong versions, bad arrays
and oversized messages are rejected with a WireError of the right kind."""

from __future__ import annotations

import dataclasses

import msgpack
import numpy as np
import pytest

from common import wire


def _unroll(T=4, N=3, obs_dim=5, act_dim=2, n_params=2) -> wire.UnrollMsg:
    rng = np.random.default_rng(0)
    return wire.UnrollMsg(
        actor_id=7, seq=11, policy_version=3,
        obs=rng.normal(size=(T, N, obs_dim)).astype(np.float32),
        next_obs=rng.normal(size=(T, N, obs_dim)).astype(np.float32),
        actions=rng.normal(size=(T, N, act_dim)).astype(np.float32),
        logp=rng.normal(size=(T, N)).astype(np.float32),
        rewards=rng.normal(size=(T, N)).astype(np.float32),
        terminated=rng.random((T, N)) < 0.2, truncated=rng.random((T, N)) < 0.2,
        params=rng.normal(size=(T, N, n_params)).astype(np.float32),
        episode_returns=[1.5, -2.0], episode_lengths=[10, 20], divergences=1, sampler_outages=2,
    )


EXAMPLES = [
    _unroll(),
    wire.WeightsMsg(policy_version=4, tensors={"a.weight": np.ones((3, 2), np.float32), "count": np.array(5.0)}),
    wire.WeightsRequestMsg(actor_id=1, have_version=-1),
    wire.HeartbeatMsg(actor_id=2, seq=9, env_steps=100),
    wire.DrawRequestMsg(n=16, client_id=3),
    wire.DrawReplyMsg(params=np.zeros((2, 3), np.float32), clip_ids=["walk", "run"], buffer_generation=4),
    wire.ValueReportMsg(params=np.zeros((5, 2), np.float32), values=np.arange(5, dtype=np.float32)),
    wire.TickMsg(iteration=12),
    wire.StatsRequestMsg(),
    wire.StatsReplyMsg(stats={"vm/min": 1.0}),
    wire.StateRequestMsg(),
    wire.StateMsg(meta={"generation": 2, "names": ["a"]}, arrays={"buffer": np.zeros((4, 2))}),
    wire.OkMsg(info="fine"),
    wire.ErrorMsg(reason="bad", error_kind="malformed"),
]


def _equal(a, b) -> bool:
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    return a == b


def test_every_message_kind_has_an_example():
    assert {type(m).KIND for m in EXAMPLES} == set(wire.MESSAGES)


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).KIND)
def test_round_trip(msg):
    frames = [bytes(f) for f in wire.encode(msg)]
    back = wire.decode(frames)
    assert type(back) is type(msg)
    for f in dataclasses.fields(msg):
        assert _equal(getattr(msg, f.name), getattr(back, f.name)), f.name


def test_no_pickle_and_zero_copy_views():
    frames = [bytes(f) for f in wire.encode(_unroll())]
    back = wire.decode(frames)
    assert not back.obs.flags.writeable  # a view of the received frame, not a copy
    assert b"pickle" not in frames[0]


@pytest.mark.parametrize(
    "frames, kind",
    [
        ([], "malformed"),
        ([b"\xc1\xff garbage"], "malformed"),
        ([msgpack.packb([1, 2, 3])], "version"),
        ([msgpack.packb({"p": "other/9", "k": "tick", "v": 1, "f": {}, "a": []})], "version"),
        ([msgpack.packb({"p": wire.PROTOCOL, "k": "tick", "v": 99, "f": {"iteration": 1}, "a": []})], "version"),
        ([msgpack.packb({"p": wire.PROTOCOL, "k": "launch_missiles", "v": 1, "f": {}, "a": []})], "unknown_kind"),
        ([msgpack.packb({"p": wire.PROTOCOL, "k": "tick", "v": 1, "f": {"bogus": 1}, "a": []})], "malformed"),
    ],
)
def test_garbage_is_rejected(frames, kind):
    with pytest.raises(wire.WireError) as err:
        wire.decode(frames)
    assert err.value.kind == kind


def test_truncated_multipart_is_rejected():
    frames = [bytes(f) for f in wire.encode(_unroll())]
    with pytest.raises(wire.WireError, match="truncated"):
        wire.decode(frames[:-1])


def test_wrong_array_size_and_dtype_are_rejected():
    frames = [bytes(f) for f in wire.encode(_unroll())]
    with pytest.raises(wire.WireError) as err:
        wire.decode([frames[0], frames[1][:-4], *frames[2:]])
    assert err.value.kind == "bad_array"
    header = msgpack.unpackb(frames[0])
    header["a"][0][1] = "|O"  # object dtype would mean pickle
    with pytest.raises(wire.WireError) as err:
        wire.decode([msgpack.packb(header), *frames[1:]])
    assert err.value.kind == "bad_array"


def test_oversized_message_is_rejected(monkeypatch):
    monkeypatch.setattr(wire, "MAX_MESSAGE_BYTES", 100)
    with pytest.raises(wire.WireError) as err:
        wire.decode([bytes(f) for f in wire.encode(_unroll())])
    assert err.value.kind == "oversized"


def test_expect_restricts_kinds():
    with pytest.raises(wire.WireError) as err:
        wire.decode(wire.encode(wire.TickMsg(iteration=1)), expect=wire.UnrollMsg)
    assert err.value.kind == "unknown_kind"


def test_nonfinite_arrays_are_caught():
    msg = _unroll()
    bad = dataclasses.replace(msg, rewards=np.full_like(msg.rewards, np.nan))
    wire.check_finite(msg)
    with pytest.raises(wire.WireError) as err:
        wire.check_finite(bad)
    assert err.value.kind == "nonfinite"
