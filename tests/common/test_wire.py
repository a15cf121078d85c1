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
        segment_clips=["walk", "run", "walk"], segment_tracked=[1, 0, 1], segment_times=[1.25, 0.4, 1.25],
    )


EXAMPLES = [
    _unroll(),
    wire.WeightsMsg(policy_version=4, tensors={"a.weight": np.ones((3, 2), np.float32), "count": np.array(5.0)}),
    wire.WeightsRequestMsg(actor_id=1, have_version=-1),
    wire.HeartbeatMsg(actor_id=2, seq=9, env_steps=100),
    wire.DrawRequestMsg(n=16, client_id=3),
    wire.DrawReplyMsg(params=np.zeros((2, 3), np.float32), clip_ids=["walk", "run"], start_s=[0.5, 0.0], buffer_generation=4),
    wire.ValueReportMsg(params=np.zeros((5, 2), np.float32), values=np.arange(5, dtype=np.float32),
                        clip_ids=["walk", "run"], clip_segments=[4, 2], clip_tracked=[3, 0],
                        fail_clip_ids=["run", "run", "walk"], fail_times_s=[0.7, 1, 0.25]),
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


# --------------------------------------------------------------------------------------------
# The generic validator: every field against its declared type and rule.


def _edit(msg, edit, extra_frames=()) -> list[bytes]:
    frames = [bytes(f) for f in wire.encode(msg)]
    header = msgpack.unpackb(frames[0])
    edit(header)
    return [msgpack.packb(header, use_bin_type=True), *frames[1:], *extra_frames]


def _add_array(h):
    h["a"].append(["extra", "<f4", [1]])


def _set_field(name, value):
    return lambda h: h["f"].__setitem__(name, value)


def _set_spec(i, j, value):
    def edit(h):
        h["a"][i][j] = value
    return edit


U = _unroll()
HB = wire.HeartbeatMsg(actor_id=2, seq=9, env_steps=100)


@pytest.mark.parametrize(
    "msg, edit, kind",
    [
        (HB, _set_field("actor_id", [1, 2]), "bad_type"),  # a list for an int (issue 22)
        (HB, _set_field("actor_id", True), "bad_type"),  # a bool is not an int
        (HB, _set_field("actor_id", 1.0), "bad_type"),  # nor is a float
        (HB, _set_field("seq", "3"), "bad_type"),  # a str for an int (issue 22)
        (HB, _set_field("seq", -2), "out_of_range"),
        (HB, _set_field("env_steps", 2**64 - 1), "out_of_range"),  # a huge int
        (HB, _set_field("final", 1), "bad_type"),
        (HB, _set_field("actor_id", {"nested": {"dict": [1]}}), "bad_type"),
        (U, _set_field("episode_returns", [1.5, float("nan")]), "nonfinite"),
        (U, _set_field("episode_returns", [1.5, "x"]), "bad_type"),
        (U, _set_field("episode_lengths", [10, 0]), "out_of_range"),
        (U, _set_field("episode_lengths", [10]), "bad_shape"),  # one length for two returns
        (U, lambda h: h["f"].pop("episode_lengths"), "bad_shape"),  # a default is held to the rules too
        (U, lambda h: h["f"].pop("seq"), "malformed"),  # a required field
        (U, _set_field("obs", [1]), "malformed"),  # an array field in the header
        (U, _set_spec(0, 1, ["<f4"]), "bad_array"),  # a dtype given as a list (issue 22)
        (U, _set_spec(0, 1, "<f8"), "bad_array"),  # an allowed dtype, but not this field's
        (U, _set_spec(0, 2, [4, 3, True]), "bad_array"),  # a bool in a shape
        (U, _set_spec(0, 2, [4, -3, -5]), "bad_array"),
        (U, _set_spec(0, 2, [2**32, 2**32, 0]), "bad_array"),  # a product that overflows int64
        (U, _set_spec(0, 2, [3, 4, 5]), "bad_shape"),  # same bytes, T and N swapped
        (U, _set_spec(0, 0, "logp"), "bad_array"),  # the same array twice
        (U, _set_spec(0, 0, 7), "bad_array"),
        (U, _add_array, "bad_array"),  # an array no field declares (with its 4-byte frame, below)
        (U, lambda h: h.__setitem__("x", 1), "malformed"),  # an unknown header entry
        (U, lambda h: h.__setitem__("v", True), "version"),  # True == 1, but not an int here
        (wire.StateMsg(meta={"a": 1}, arrays={}), _set_field("meta", {"a": [[[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]]]}),
         "out_of_range"),  # nested deeper than MAX_DEPTH
        (wire.WeightsMsg(policy_version=1, tensors={"w": np.ones(2, np.float32)}), _set_field("tensors", ["w", "w"]),
         "bad_array"),
        (wire.DrawReplyMsg(params=np.zeros((2, 3), np.float32), clip_ids=["a", "b"]), _set_field("clip_ids", ["a"]),
         "bad_shape"),
        (U, _set_field("segment_tracked", [1, 2, 0]), "out_of_range"),  # a segment is tracked or not
        (U, _set_field("segment_tracked", [1, 0]), "bad_shape"),  # two outcomes for three segments
        (U, _set_field("segment_clips", ["walk", 3, "run"]), "bad_type"),
        (EXAMPLES[6], _set_field("clip_segments", [4, -1]), "out_of_range"),
        (EXAMPLES[6], _set_field("clip_tracked", [3]), "bad_shape"),
        (EXAMPLES[6], _set_field("clip_segments", [4, 2**40]), "out_of_range"),
        # start and failure times (the sampler's time bins): one per draw or failure, finite, >= 0
        (EXAMPLES[5], _set_field("start_s", [0.5]), "bad_shape"),
        (EXAMPLES[5], _set_field("start_s", [0.5, -0.1]), "out_of_range"),
        (EXAMPLES[5], _set_field("start_s", [0.5, float("nan")]), "nonfinite"),
        (EXAMPLES[5], _set_field("start_s", [0.5, "0"]), "bad_type"),
        (EXAMPLES[6], _set_field("fail_times_s", [0.7, 1.0]), "bad_shape"),
        (EXAMPLES[6], _set_field("fail_times_s", [0.7, float("inf"), 0.2]), "nonfinite"),
        (EXAMPLES[6], _set_field("fail_times_s", [0.7, True, 0.2]), "bad_type"),
        (EXAMPLES[6], _set_field("fail_times_s", [0.7, 1e7, 0.2]), "out_of_range"),
        (EXAMPLES[6], _set_field("fail_clip_ids", ["run"] * (wire.MAX_FAILURE_TIMES + 1)), "out_of_range"),
        (U, _set_field("segment_times", [1.0, -2.0, 1.0]), "out_of_range"),
        (U, _set_field("segment_times", [1.0]), "bad_shape"),
    ],
)
def test_every_field_is_checked_against_its_declaration(msg, edit, kind):
    with pytest.raises(wire.WireError) as err:
        wire.decode(_edit(msg, edit, [b"\0\0\0\0"] if edit is _add_array else []))
    assert err.value.kind == kind, err.value


def test_bool_arrays_hold_only_zero_and_one():
    frames = [bytes(f) for f in wire.encode(_unroll())]
    i = 1 + [s[0] for s in msgpack.unpackb(frames[0])["a"]].index("terminated")
    frames[i] = b"\x02" + frames[i][1:]
    with pytest.raises(wire.WireError) as err:
        wire.decode(frames)
    assert err.value.kind == "bad_array"


def test_float_fields_take_ints_and_empty_clip_lists_are_allowed():
    msg = wire.decode(_edit(wire.StatsReplyMsg(stats={"a": 1.0}), _set_field("stats", {"a": 3})))
    assert msg.stats == {"a": 3.0} and type(msg.stats["a"]) is float
    assert wire.decode(wire.encode(wire.DrawReplyMsg(params=np.zeros((2, 3), np.float32)))).clip_ids == []
    # Fields declared non-finite keep NaN (a fit loss before the first fit).
    assert np.isnan(wire.decode(wire.encode(wire.StatsReplyMsg(stats={"loss": float("nan")}))).stats["loss"])


def test_a_receiver_pins_shape_names():
    frames = wire.encode(_unroll(T=4, N=3))
    assert wire.decode(frames, dims={"T": 4, "N": 3, "obs_dim": 5}).obs.shape == (4, 3, 5)
    for dims in ({"T": 32}, {"N": 8}, {"obs_dim": 6}, {"act_dim": 3}, {"n_params": 1}):
        with pytest.raises(wire.WireError) as err:
            wire.decode(frames, dims=dims)
        assert err.value.kind == "bad_shape", dims


@pytest.mark.parametrize("frames", [b"bytes", None, 5, "text", [5], [None], [b"\x91" * 1000 + b"\xc0"],
                                    [b"\x91" * 5000 + b"\xc0"], [memoryview(np.zeros((2, 2))).cast("B")[::2]]])
def test_decode_raises_only_wire_errors_on_any_input(frames):
    with pytest.raises(wire.WireError):
        wire.decode(frames)
