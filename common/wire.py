"""The wire contract: every message that crosses a socket, defined once, and its codec.

A message is a frozen dataclass. On the wire it is a ZeroMQ multipart message:

    frame 0   msgpack header {"p": PROTOCOL, "k": kind, "v": version, "f": {scalar fields},
                              "a": [[name, dtype, shape], ...]}
    frame 1+  the raw bytes of each array, in the order of "a", C-contiguous, little-endian

Arrays are decoded zero-copy with `np.frombuffer` (read-only views of the received frames).
Pickle is never used: a peer can only make us build numbers, strings, lists, dicts and arrays
of a few plain dtypes. Anything else raises `WireError` with the reason; callers count it and
keep serving (see the vLLM `serial_utils.py` pattern cited in STYLE.md).

Field kinds a message may declare:
    int, float, str, bool, list[...], dict[str, ...], Any  -> msgpack header
    np.ndarray                                              -> one array frame
    dict[str, np.ndarray]                                   -> one array frame per entry, named "field/key"

Every field is checked on decode against its declared type and its `rule(...)` (the range,
length and shape rules written beside the field), by one generic validator (`_check`):

    bool is not an int; an int field takes exactly an int in [ge, le] (default +-MAX_INT);
    a float field takes an int or a float, NaN/Inf refused unless `finite=False`;
    str, list and dict sizes are capped; dict keys are str; `Any` is plain msgpack data nested
    at most MAX_DEPTH deep;
    an array's spec is [name: str, dtype in ALLOWED_DTYPES, shape: list of ints >= 0], its frame
    holds exactly prod(shape) * itemsize bytes, the spec list names exactly the arrays the
    fields declare; a field's dtype is one of its rule's `dtypes`, its shape matches the rule's
    `shape` (ints fixed, names such as "T" the same in every field of the message, and equal to
    `decode(..., dims=)` where the receiver pins them); a bool array holds only bytes 0 and 1;
    a float array is finite unless `finite=False`.

`decode` raises nothing but `WireError`, whatever it is given.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from typing import Any, ClassVar

import msgpack
import numpy as np

PROTOCOL = "morphmimic/1"
MAX_MESSAGE_BYTES = 256 * 1024 * 1024
"""Refuse any message bigger than this (sum of frames); a 3x1024 policy is about 30 MB."""

ALLOWED_DTYPES = frozenset({"<f4", "<f8", "<i4", "<i8", "|u1", "|b1", "<f2", "<u4"})
F32 = frozenset({"<f4"})
BOOL = frozenset({"|b1"})
I32 = frozenset({"<i4"})

MAX_INT = 2**53
"""Default bound of every int field: exact as a float64, so counters and logs stay exact."""
MAX_ACTOR_ID = 2**16 - 1
MAX_STR = 1 << 16
"""Default longest str field (characters)."""
MAX_KEY = 256
"""Longest dict key and array name."""
MAX_ITEMS = 1 << 20
"""Default most entries of a list or dict field."""
MAX_COUNT = 1 << 31
"""Largest count a message may carry (segment counts)."""
MAX_CLIP_S = 1e6
"""Largest clip time (s) a message may carry; the sampler checks each against its clip's length."""
MAX_FAILURE_TIMES = 8192
"""Most failure times one value report carries (the learner keeps the first ones of an iteration)."""
MAX_DEPTH = 16
"""Deepest nesting of an `Any` field (a sampler state's meta is 2 deep)."""
MAX_NDIM = 8

ERROR_KINDS = (
    "malformed", "version", "unknown_kind", "oversized", "bad_type", "out_of_range", "bad_array",
    "bad_shape", "nonfinite",
)
"""The counter buckets of `WireError.kind` raised by `decode`."""


class WireError(ValueError):
    """A message that cannot be decoded: names the field or frame and what was expected."""

    def __init__(self, reason: str, kind: str = "malformed"):
        super().__init__(reason)
        self.kind = kind
        """Counter bucket: malformed (not msgpack, wrong frame count, missing or unknown fields) |
        version | unknown_kind | oversized | bad_type (a field of another type) | out_of_range
        (an int, float, length or size outside its rule) | bad_array (array spec or frame) |
        bad_shape (shape rule or the receiver's pinned dims) | nonfinite. Receivers add their
        own: unknown_actor, invalid (a service's semantic check), internal (a bug, counted)."""


@dataclass(frozen=True)
class Rule:
    """What a field's value may be, beyond its type. Written beside the field with `rule(...)`."""

    ge: float | None = None
    """Smallest int/float (each element of a list, each value of a dict)."""
    le: float | None = None
    finite: bool = True
    """Floats and float arrays: refuse NaN and Inf."""
    max_len: int = MAX_STR
    """Longest str (each str element of a list)."""
    max_items: int = MAX_ITEMS
    """Most entries of a list or dict (arrays of a dict[str, np.ndarray])."""
    length: str | None = None
    """A list's length is this shape name (the same in every field that uses it)."""
    empty_ok: bool = False
    """... or the list is empty."""
    shape: tuple[int | str, ...] | None = None
    """Arrays: exact rank; an int is a fixed size, a str a name shared across the message's fields."""
    dtypes: frozenset[str] = ALLOWED_DTYPES
    """Arrays (each array of a dict): allowed dtypes."""


def rule(**kw: Any) -> dict[str, Rule]:
    """Field metadata: `x: int = field(metadata=rule(ge=0))`."""
    return {"wire": Rule(**kw)}


# --------------------------------------------------------------------------------------------
# Messages. Bump `VERSION` on a message when its fields change meaning or shape.


@dataclass(frozen=True)
class UnrollMsg:
    """T control steps of N environments from one rollout actor (actor -> learner, PUSH).

    Arrays are time-major `[T, N, ...]`. `next_obs[t]` is the observation after step t *before*
    any reset, so a truncated episode can be bootstrapped from its true last state. The learner
    pins T, N, obs_dim, act_dim and n_params to its configuration.
    """

    KIND: ClassVar[str] = "unroll"
    VERSION: ClassVar[int] = 4
    actor_id: int = field(metadata=rule(ge=0, le=MAX_ACTOR_ID))
    seq: int = field(metadata=rule(ge=0))
    """Per-actor sequence number, +1 per unroll; gaps mean lost unrolls."""
    policy_version: int = field(metadata=rule(ge=0))
    """Version of the weights that chose these actions."""
    obs: np.ndarray = field(metadata=rule(shape=("T", "N", "obs_dim"), dtypes=F32))  # raw (not normalized)
    next_obs: np.ndarray = field(metadata=rule(shape=("T", "N", "obs_dim"), dtypes=F32))
    actions: np.ndarray = field(metadata=rule(shape=("T", "N", "act_dim"), dtypes=F32))  # pre-squash Gaussian samples
    logp: np.ndarray = field(metadata=rule(shape=("T", "N"), dtypes=F32))  # behaviour log-probability of `actions`
    rewards: np.ndarray = field(metadata=rule(shape=("T", "N"), dtypes=F32))
    terminated: np.ndarray = field(metadata=rule(shape=("T", "N"), dtypes=BOOL))  # no bootstrap (fall, task end, divergence)
    truncated: np.ndarray = field(metadata=rule(shape=("T", "N"), dtypes=BOOL))  # bootstrap from next_obs (time limit)
    params: np.ndarray = field(metadata=rule(shape=("T", "N", "n_params"), dtypes=F32))
    """The episode's sampled task/shape parameters."""
    episode_returns: list[float] = field(default_factory=list, metadata=rule(length="episodes"))
    """Undiscounted returns of the episodes that ended inside this unroll."""
    episode_lengths: list[int] = field(default_factory=list, metadata=rule(ge=1, length="episodes"))
    divergences: int = field(default=0, metadata=rule(ge=0))
    """Episodes that ended in this unroll because the simulation diverged (a MuJoCo divergence
    warning, or a non-finite observation or reward); each is also a `terminated` step."""
    sampler_outages: int = field(default=0, metadata=rule(ge=0))
    """Draws that fell back to the previous parameters because the sampler did not answer."""
    segment_clips: list[str] = field(default_factory=list, metadata=rule(length="segments", empty_ok=True, max_len=MAX_KEY))
    """Clips of the training segments that ended inside this unroll (tasks that track clips)."""
    segment_tracked: list[int] = field(default_factory=list, metadata=rule(ge=0, le=1, length="segments", empty_ok=True))
    """1 for a segment tracked to its clip's end, 0 for one a termination ended."""
    segment_times: list[float] = field(default_factory=list, metadata=rule(ge=0, le=MAX_CLIP_S, length="segments", empty_ok=True))
    """Clip time (s) at which each segment ended: where an untracked one failed (the sampler's
    time bins), its clip's length for a tracked one; empty from a sender that does not tell."""
    clip_names: list[str] = field(default_factory=list, metadata=rule(max_len=MAX_KEY, max_items=4096))
    """The clips `step_clips` indexes (tasks that track clips); empty: none."""
    step_clips: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.int32), metadata=rule(dtypes=I32))
    """`[T, N]` int32: the clip each step's episode was drawn with, an index into `clip_names`,
    -1 for none; or empty (`[0, 0]`): the sender does not tell. The learner sends it with the value
    pairs to a sampler that fits Vm over (shape, class); `learner.unroll_bounds` checks the
    shape and the indices."""


@dataclass(frozen=True)
class WeightsMsg:
    """Policy weights and observation-normalizer statistics (learner -> actors, PUB or reply)."""

    KIND: ClassVar[str] = "weights"
    VERSION: ClassVar[int] = 1
    policy_version: int = field(metadata=rule(ge=0))
    tensors: dict[str, np.ndarray] = field(metadata=rule(max_items=4096))
    """The actor-side state dict (policy mean network, log-std, normalizer buffers)."""


@dataclass(frozen=True)
class WeightsRequestMsg:
    """An actor asks for the current weights on (re)connect: PUB drops slow joiners."""

    KIND: ClassVar[str] = "weights_request"
    VERSION: ClassVar[int] = 1
    actor_id: int = field(metadata=rule(ge=0, le=MAX_ACTOR_ID))
    have_version: int = field(default=-1, metadata=rule(ge=-1))


@dataclass(frozen=True)
class HeartbeatMsg:
    """An actor is alive (actor -> learner over the unroll channel)."""

    KIND: ClassVar[str] = "heartbeat"
    VERSION: ClassVar[int] = 2
    actor_id: int = field(metadata=rule(ge=0, le=MAX_ACTOR_ID))
    seq: int = field(metadata=rule(ge=-1))
    """The sequence number of the last unroll numbered (sent or given up), -1 before the first:
    on the same pipe as the unrolls, so any number up to it that never arrived is lost."""
    env_steps: int = field(metadata=rule(ge=0))
    final: bool = False
    """The actor stopped: nothing follows (the learner drains until every actor said so)."""


@dataclass(frozen=True)
class DrawRequestMsg:
    """Ask the sampler for `n` episode parameter draws."""

    KIND: ClassVar[str] = "draw_request"
    VERSION: ClassVar[int] = 1
    n: int = field(metadata=rule(ge=1))
    client_id: int = field(default=0, metadata=rule(ge=0))


@dataclass(frozen=True)
class DrawReplyMsg:
    """`n` episode draws: task/shape parameter vectors and motion clip ids."""

    KIND: ClassVar[str] = "draw_reply"
    VERSION: ClassVar[int] = 2
    params: np.ndarray = field(metadata=rule(shape=("n", "n_params"), dtypes=F32))  # in the task's parameter order
    clip_ids: list[str] = field(default_factory=list, metadata=rule(length="n", empty_ok=True, max_len=MAX_KEY))
    """One clip id per draw, or empty when the task uses no motion clips."""
    start_s: list[float] = field(default_factory=list, metadata=rule(ge=0, le=MAX_CLIP_S, length="n", empty_ok=True))
    """One start time (s) in its clip per draw (the sampler's failure-weighted time bins), or
    empty: the environment draws a uniform start."""
    buffer_generation: int = field(default=0, metadata=rule(ge=0))
    """How many MCMC refills have happened: lets a client see stale draws."""


@dataclass(frozen=True)
class ValueReportMsg:
    """`(parameters, V(s))` pairs for the marginal value fit (Won & Lee 2019, Alg. 1)."""

    KIND: ClassVar[str] = "value_report"
    VERSION: ClassVar[int] = 5
    params: np.ndarray = field(metadata=rule(shape=("m", "n_params"), dtypes=F32))
    values: np.ndarray = field(metadata=rule(shape=("m",), dtypes=F32))
    report_id: str = field(default="", metadata=rule(max_len=128))
    """Names this report: a resend with the same id (a retry after a lost reply) is stored once.
    Empty: never deduplicated."""
    clip_ids: list[str] = field(default_factory=list, metadata=rule(length="k", empty_ok=True, max_len=MAX_KEY))
    """Clips whose training segments this report counts (adaptive clip sampling); empty: none."""
    clip_segments: list[int] = field(default_factory=list, metadata=rule(ge=0, le=MAX_COUNT, length="k", empty_ok=True))
    """Segments per clip since the last report."""
    clip_tracked: list[int] = field(default_factory=list, metadata=rule(ge=0, le=MAX_COUNT, length="k", empty_ok=True))
    """Of those, the segments tracked to the clip's end (the sampler checks tracked <= segments)."""
    fail_clip_ids: list[str] = field(default_factory=list, metadata=rule(
        length="f", empty_ok=True, max_len=MAX_KEY, max_items=MAX_FAILURE_TIMES))
    """The clip of each failed segment since the last report (the sampler's time bins); empty: none."""
    fail_times_s: list[float] = field(default_factory=list, metadata=rule(
        ge=0, le=MAX_CLIP_S, length="f", empty_ok=True, max_items=MAX_FAILURE_TIMES))
    """The clip time (s) each failed there (the sampler checks each is inside its clip)."""
    pair_clip_ids: list[str] = field(default_factory=list, metadata=rule(length="m", empty_ok=True, max_len=MAX_KEY))
    """The clip of each pair's episode, one per params row (a sampler with `shape_by_class` fits
    Vm over (shape, class) and refuses a report without them or with a clip it does not draw;
    one without refuses any); empty: none."""


@dataclass(frozen=True)
class TickMsg:
    """One policy iteration has finished (learner -> sampler); may trigger an MCMC refill."""

    KIND: ClassVar[str] = "tick"
    VERSION: ClassVar[int] = 1
    iteration: int = field(metadata=rule(ge=0))


@dataclass(frozen=True)
class StatsRequestMsg:
    KIND: ClassVar[str] = "stats_request"
    VERSION: ClassVar[int] = 1


@dataclass(frozen=True)
class StatsReplyMsg:
    """Flat metric name -> number, logged by the learner under `sampler/`."""

    KIND: ClassVar[str] = "stats_reply"
    VERSION: ClassVar[int] = 1
    stats: dict[str, float] = field(metadata=rule(finite=False))
    """NaN is a legitimate value here (e.g. the fit loss before the first fit)."""


@dataclass(frozen=True)
class StateRequestMsg:
    """Ask the sampler for its whole state (it goes into the learner's checkpoint)."""

    KIND: ClassVar[str] = "state_request"
    VERSION: ClassVar[int] = 1


@dataclass(frozen=True)
class StateMsg:
    """A service's state: primitives in `meta`, arrays in `arrays` (checkpointable as is).
    The receiver checks what the values mean (the sampler restores into a copy first)."""

    KIND: ClassVar[str] = "state"
    VERSION: ClassVar[int] = 1
    meta: dict[str, Any] = field(metadata=rule(max_items=4096))
    arrays: dict[str, np.ndarray] = field(metadata=rule(max_items=4096, finite=False))


@dataclass(frozen=True)
class OkMsg:
    KIND: ClassVar[str] = "ok"
    VERSION: ClassVar[int] = 1
    info: str = ""


@dataclass(frozen=True)
class ErrorMsg:
    """A request was refused; `reason` names the value and what was allowed."""

    KIND: ClassVar[str] = "error"
    VERSION: ClassVar[int] = 1
    reason: str
    error_kind: str = field(default="malformed", metadata=rule(max_len=64))


MESSAGES: dict[str, type] = {
    cls.KIND: cls
    for cls in (
        UnrollMsg,
        WeightsMsg,
        WeightsRequestMsg,
        HeartbeatMsg,
        DrawRequestMsg,
        DrawReplyMsg,
        ValueReportMsg,
        TickMsg,
        StatsRequestMsg,
        StatsReplyMsg,
        StateRequestMsg,
        StateMsg,
        OkMsg,
        ErrorMsg,
    )
}


# --------------------------------------------------------------------------------------------
# Schema: each message class's fields, read once from its type hints and rules.


@dataclass(frozen=True)
class _Field:
    name: str
    hint: Any
    kind: str
    """'array', 'array_dict' or 'plain'."""
    rule: Rule
    required: bool
    default: Any = None
    """Makes the default value (checked like a sent one: e.g. a list's length binds its name)."""


_PLAIN_SCALARS = (int, float, str, bool)


def _supported(hint: Any) -> bool:
    if hint is Any or hint in _PLAIN_SCALARS:
        return True
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is list:
        return len(args) == 1 and _supported(args[0])
    if origin is dict:
        return len(args) == 2 and args[0] is str and _supported(args[1])
    return False


def _schema(cls: type) -> tuple[_Field, ...]:
    cached = cls.__dict__.get("_wire_schema")
    if cached is not None:
        return cached
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        if hint is np.ndarray:
            kind = "array"
        elif typing.get_origin(hint) is dict and typing.get_args(hint) == (str, np.ndarray):
            kind = "array_dict"
        elif _supported(hint):
            kind = "plain"
        else:
            raise TypeError(f"{cls.__name__}.{f.name}: type {hint} cannot cross the wire")
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        default = None if required else f.default_factory if f.default is dataclasses.MISSING else (lambda v=f.default: v)
        out.append(_Field(f.name, hint, kind, f.metadata.get("wire", Rule()), required, default))
    schema = tuple(out)
    type.__setattr__(cls, "_wire_schema", schema)
    return schema


def _field_kinds(cls: type) -> dict[str, str]:
    """Map each field of a message class to 'array', 'array_dict' or 'plain'."""
    return {f.name: f.kind for f in _schema(cls)}


for _cls in MESSAGES.values():  # a field type the codec cannot carry fails at import, not on a peer's message
    _schema(_cls)


# --------------------------------------------------------------------------------------------
# Codec


def encode(msg: Any) -> list[bytes | memoryview]:
    """Encode a message into multipart frames (header + raw arrays). No copies of the arrays
    beyond making them C-contiguous little-endian."""
    cls = type(msg)
    if MESSAGES.get(getattr(cls, "KIND", None)) is not cls:
        raise TypeError(f"{cls.__name__} is not a wire message; known kinds: {sorted(MESSAGES)}")
    plain: dict[str, Any] = {}
    specs: list[list[Any]] = []
    frames: list[bytes | memoryview] = []

    def add(name: str, value: Any) -> None:
        arr = np.asarray(value)
        if not arr.flags.c_contiguous:  # NOTE: not ascontiguousarray: it turns 0-d arrays into 1-d
            arr = arr.copy(order="C")
        if arr.dtype.byteorder == ">":
            arr = arr.astype(arr.dtype.newbyteorder("<"))
        dtype = arr.dtype.str
        if dtype not in ALLOWED_DTYPES:
            raise TypeError(f"array {name!r} has dtype {dtype}; allowed: {sorted(ALLOWED_DTYPES)}")
        specs.append([name, dtype, list(arr.shape)])
        frames.append(memoryview(arr).cast("B") if arr.size else b"")

    for name, kind in _field_kinds(cls).items():
        value = getattr(msg, name)
        if kind == "array":
            add(name, value)
        elif kind == "array_dict":
            for key, arr in value.items():
                add(f"{name}/{key}", arr)
            plain[name] = list(value.keys())
        else:
            plain[name] = value
    header = msgpack.packb(
        {"p": PROTOCOL, "k": cls.KIND, "v": cls.VERSION, "f": plain, "a": specs},
        use_bin_type=True,
    )
    return [header, *frames]


def _show(value: Any) -> str:
    """A peer's value in an error message, bounded."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _type_name(hint: Any) -> str:
    return getattr(hint, "__name__", None) or str(hint).replace("typing.", "")


def _range(value: float, r: Rule, where: str, lo: float = -math.inf, hi: float = math.inf) -> None:
    """`value` within the rule's [ge, le]; `lo`/`hi` stand in for a bound the rule leaves open."""
    lo = lo if r.ge is None else r.ge
    hi = hi if r.le is None else r.le
    if not lo <= value <= hi:
        show = lambda x: str(x) if isinstance(x, int) else f"{x:g}"
        raise WireError(f"{where} = {_show(value)} is out of range; allowed: [{show(lo)}, {show(hi)}]", "out_of_range")


def _bind(dims: dict[str, int], name: str, size: int, where: str, kind: str = "bad_shape") -> None:
    have = dims.setdefault(name, size)
    if have != size:
        raise WireError(f"{where}: {name} = {size} here but {have} elsewhere in the message", kind)


def _check_any(value: Any, where: str, depth: int) -> None:
    """Plain msgpack data (what `Any` fields may hold), nested at most MAX_DEPTH deep."""
    if depth > MAX_DEPTH:
        raise WireError(f"{where} is nested deeper than {MAX_DEPTH}", "out_of_range")
    if value is None or type(value) in (bool, int, float, str):
        return
    if type(value) is list:
        for i, v in enumerate(value):
            _check_any(v, f"{where}[{i}]", depth + 1)
    elif type(value) is dict:
        for k, v in value.items():
            if type(k) is not str:
                raise WireError(f"{where} has a key {_show(k)}; keys are str", "bad_type")
            _check_any(v, f"{where}[{k!r}]", depth + 1)
    else:
        raise WireError(f"{where} = {_show(value)}: {type(value).__name__} is not plain data", "bad_type")


def _check(value: Any, hint: Any, r: Rule, where: str, dims: dict[str, int]) -> Any:
    """`value` as the declared type `hint` under rule `r`, or WireError. Ints become floats in
    float fields; nothing else is converted."""
    if hint is Any:
        _check_any(value, where, 0)
        return value
    if hint is bool:
        if type(value) is not bool:
            raise WireError(f"{where} = {_show(value)}: expected a bool", "bad_type")
        return value
    if hint is int:
        if type(value) is not int:  # NOTE: type(True) is bool, so a bool is not an int here
            raise WireError(f"{where} = {_show(value)}: expected an int", "bad_type")
        _range(value, r, where, -MAX_INT, MAX_INT)
        return value
    if hint is float:
        if type(value) not in (int, float):
            raise WireError(f"{where} = {_show(value)}: expected a float", "bad_type")
        value = float(value)
        if not math.isfinite(value):
            if r.finite:
                raise WireError(f"{where} = {value}: expected a finite float", "nonfinite")
            return value
        _range(value, r, where)
        return value
    if hint is str:
        if type(value) is not str:
            raise WireError(f"{where} = {_show(value)}: expected a str", "bad_type")
        if len(value) > r.max_len:
            raise WireError(f"{where}: a str of {len(value)} characters; at most {r.max_len}", "out_of_range")
        return value
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is list:
        if type(value) is not list:
            raise WireError(f"{where} = {_show(value)}: expected a {_type_name(hint)}", "bad_type")
        if len(value) > r.max_items:
            raise WireError(f"{where}: {len(value)} items; at most {r.max_items}", "out_of_range")
        if r.length is not None and not (r.empty_ok and not value):
            _bind(dims, r.length, len(value), where)
        return [_check(v, args[0], r, f"{where}[{i}]", dims) for i, v in enumerate(value)]
    if origin is dict:
        if type(value) is not dict:
            raise WireError(f"{where} = {_show(value)}: expected a {_type_name(hint)}", "bad_type")
        if len(value) > r.max_items:
            raise WireError(f"{where}: {len(value)} entries; at most {r.max_items}", "out_of_range")
        out = {}
        for k, v in value.items():
            if type(k) is not str or len(k) > MAX_KEY:
                raise WireError(f"{where} has a key {_show(k)}; keys are str of at most {MAX_KEY} characters", "bad_type")
            out[k] = _check(v, args[1], r, f"{where}[{k!r}]", dims)
        return out
    raise WireError(f"{where}: no check for type {hint}", "malformed")  # unreachable: _schema refuses it


def _buffer(frame: Any, i: int) -> memoryview:
    buf = frame.buffer if hasattr(frame, "buffer") else frame  # zmq.Frame
    if not isinstance(buf, (bytes, bytearray, memoryview)):
        raise WireError(f"frame {i} is a {type(buf).__name__}, not bytes", "malformed")
    view = memoryview(buf)
    if view.format != "B" or view.ndim != 1:
        view = view.cast("B")  # a non-contiguous view raises TypeError: caught by `decode`
    return view


def _array_spec(spec: Any, kind: str) -> tuple[str, str, tuple[int, ...]]:
    if type(spec) is not list or len(spec) != 3:
        raise WireError(f"{kind} array spec {_show(spec)} is not [name, dtype, shape]", "bad_array")
    name, dtype, shape = spec
    if type(name) is not str or not 0 < len(name) <= 2 * MAX_KEY:
        raise WireError(f"{kind} array name {_show(name)} is not a str of 1..{2 * MAX_KEY} characters", "bad_array")
    if type(dtype) is not str or dtype not in ALLOWED_DTYPES:
        raise WireError(f"{kind} array {name!r}: dtype {_show(dtype)}; allowed: {sorted(ALLOWED_DTYPES)}", "bad_array")
    if (type(shape) is not list or len(shape) > MAX_NDIM
            or any(type(s) is not int or not 0 <= s <= MAX_MESSAGE_BYTES for s in shape)):
        raise WireError(f"{kind} array {name!r}: shape {_show(shape)} is not a list of at most {MAX_NDIM} "
                        f"ints in [0, {MAX_MESSAGE_BYTES}]", "bad_array")
    return name, dtype, tuple(shape)


def decode(frames: Any, expect: type | tuple[type, ...] | None = None, dims: dict[str, int] | None = None) -> Any:
    """Decode multipart frames into a message; raise `WireError` on anything malformed, and
    never anything else.

    `frames` may be bytes, memoryviews or zmq.Frame objects (their `.buffer` is used).
    `expect` restricts which message classes are acceptable here. `dims` pins shape names
    (e.g. {"T": 32, "N": 8, "obs_dim": 12}): a message whose arrays bind one otherwise is
    rejected ("bad_shape").
    """
    try:
        return _decode(frames, expect, dims)
    except WireError:
        raise
    except Exception as exc:  # noqa: BLE001 - e.g. RecursionError, MemoryError, a peer's exotic input
        raise WireError(f"undecodable message ({type(exc).__name__}: {_show(str(exc))})", "malformed") from None


def _decode(frames: Any, expect: type | tuple[type, ...] | None, dims: dict[str, int] | None) -> Any:
    if not isinstance(frames, (list, tuple)):
        raise WireError(f"expected a list of frames, got {type(frames).__name__}", "malformed")
    if not frames:
        raise WireError("empty message: expected a msgpack header frame")
    bufs = [_buffer(f, i) for i, f in enumerate(frames)]
    total = sum(b.nbytes for b in bufs)
    if total > MAX_MESSAGE_BYTES:
        raise WireError(f"message of {total} bytes exceeds the limit of {MAX_MESSAGE_BYTES}", "oversized")
    try:
        header = msgpack.unpackb(bufs[0], raw=False, strict_map_key=True, max_bin_len=0, max_ext_len=0)
    except Exception as exc:  # noqa: BLE001 - msgpack raises several unrelated types
        raise WireError(f"header is not valid msgpack ({type(exc).__name__}: {_show(str(exc))})") from None
    if type(header) is not dict or header.get("p") != PROTOCOL:
        got = header.get("p") if type(header) is dict else type(header).__name__
        raise WireError(f"protocol {_show(got)} is not {PROTOCOL!r}", "version")
    kind, version = header.get("k"), header.get("v")
    cls = MESSAGES.get(kind) if type(kind) is str else None
    if cls is None:
        raise WireError(f"unknown message kind {_show(kind)}; known: {sorted(MESSAGES)}", "unknown_kind")
    if type(version) is not int or version != cls.VERSION:
        raise WireError(f"{kind} version {_show(version)} is not the supported {cls.VERSION}", "version")
    if expect is not None and not issubclass(cls, expect):
        raise WireError(f"message kind {kind!r} is not accepted on this socket", "unknown_kind")
    extra = set(header) - {"p", "k", "v", "f", "a"}
    if extra:
        raise WireError(f"{kind} header has unknown entries {_show(sorted(extra))}")
    plain, specs = header.get("f"), header.get("a")
    if type(plain) is not dict or type(specs) is not list:
        raise WireError(f"{kind} header lacks its field map or array list")
    if len(specs) != len(bufs) - 1:
        raise WireError(f"{kind} declares {len(specs)} arrays but carries {len(bufs) - 1} frames (truncated?)")

    schema = _schema(cls)
    names = {f.name for f in schema}
    unknown = [k for k in plain if k not in names]
    if unknown:
        raise WireError(f"{kind} has unknown fields {_show(unknown)}; fields: {sorted(names)}")
    bound: dict[str, int] = {}
    values: dict[str, Any] = {}
    expected_arrays: list[str] = []
    for f in schema:
        where = f"{kind}.{f.name}"
        if f.kind == "array":
            if f.name in plain:
                raise WireError(f"{where} is an array: it travels as a frame, not in the header")
            expected_arrays.append(f.name)
        elif f.kind == "array_dict":
            if f.name not in plain:
                raise WireError(f"{kind} lacks the key list of array map {f.name!r}")
            keys = _check(plain[f.name], list[str], dataclasses.replace(f.rule, max_len=MAX_KEY), where, bound)
            if len(set(keys)) != len(keys):
                raise WireError(f"{where} lists a key twice", "bad_array")
            expected_arrays += [f"{f.name}/{k}" for k in keys]
        elif f.name in plain:
            values[f.name] = _check(plain[f.name], f.hint, f.rule, where, bound)
        elif f.required:
            raise WireError(f"{kind} lacks the field {f.name!r}")
        else:  # absent: its default, held to the same rules (a shape name it binds, above all)
            values[f.name] = _check(f.default(), f.hint, f.rule, where + " (default)", bound)

    arrays: dict[str, np.ndarray] = {}
    for spec, buf in zip(specs, bufs[1:]):
        name, dtype, shape = _array_spec(spec, kind)
        if name in arrays:
            raise WireError(f"{kind} carries the array {name!r} twice", "bad_array")
        expected = math.prod(shape) * np.dtype(dtype).itemsize
        if buf.nbytes != expected:
            raise WireError(f"{kind} array {name!r}: {buf.nbytes} bytes for shape {list(shape)} {dtype} "
                            f"(expected {expected})", "bad_array")
        arrays[name] = np.frombuffer(buf, dtype=dtype).reshape(shape) if expected else np.zeros(shape, dtype)
    if sorted(arrays) != sorted(expected_arrays):
        missing = sorted(set(expected_arrays) - set(arrays))
        extra = sorted(set(arrays) - set(expected_arrays))
        raise WireError(f"{kind} arrays do not match its fields: missing {_show(missing)}, unexpected {_show(extra)}",
                        "bad_array")

    checked: list[tuple[str, np.ndarray, Rule]] = []
    for f in schema:
        if f.kind == "array":
            values[f.name] = arrays[f.name]
            checked.append((f.name, arrays[f.name], f.rule))
        elif f.kind == "array_dict":
            values[f.name] = {k: arrays[f"{f.name}/{k}"] for k in plain[f.name]}
            checked += [(f"{f.name}/{k}", a, f.rule) for k, a in values[f.name].items()]
    for name, arr, r in checked:
        if arr.dtype.str not in r.dtypes:
            raise WireError(f"{kind} array {name!r} is {arr.dtype.str}; allowed: {sorted(r.dtypes)}", "bad_array")
        if r.shape is not None:
            if arr.ndim != len(r.shape):
                raise WireError(f"{kind} array {name!r} has shape {list(arr.shape)}; expected {list(r.shape)}", "bad_shape")
            for size, want in zip(arr.shape, r.shape):
                if isinstance(want, str):
                    _bind(bound, want, size, f"{kind} array {name!r} shape {list(arr.shape)}")
                elif size != want:
                    raise WireError(f"{kind} array {name!r} has shape {list(arr.shape)}; expected {list(r.shape)}", "bad_shape")
    for name, want in (dims or {}).items():
        if name in bound and bound[name] != want:
            raise WireError(f"{kind}: {name} = {bound[name]}; this receiver expects {name} = {want}", "bad_shape")
    for name, arr, r in checked:
        if arr.dtype == np.bool_ and arr.size and arr.view(np.uint8).max() > 1:
            raise WireError(f"{kind} array {name!r} is bool but holds bytes other than 0 and 1", "bad_array")
        if r.finite and arr.dtype.kind == "f" and not np.isfinite(arr).all():
            raise WireError(f"{kind} array {name!r} holds NaN or Inf", "nonfinite")
    return cls(**values)


def check_finite(msg: Any) -> None:
    """Raise `WireError('nonfinite')` if any float array of `msg` holds NaN or Inf (whatever
    its rule says: a service that wants every array finite calls this after `decode`)."""
    for name, kind in _field_kinds(type(msg)).items():
        value = getattr(msg, name)
        items = value.items() if kind == "array_dict" else [(name, value)] if kind == "array" else []
        for key, arr in items:
            if arr.dtype.kind == "f" and not np.isfinite(arr).all():
                raise WireError(f"{type(msg).KIND} array {key!r} holds NaN or Inf", "nonfinite")
