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
    scalars, str, bool, lists/dicts of those  -> msgpack header
    np.ndarray                                -> one array frame
    dict[str, np.ndarray]                     -> one array frame per entry, named "field/key"
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field
from typing import Any, ClassVar

import msgpack
import numpy as np

PROTOCOL = "morphmimic/1"
MAX_MESSAGE_BYTES = 256 * 1024 * 1024
"""Refuse any message bigger than this (sum of frames); a 3x1024 policy is about 30 MB."""

ALLOWED_DTYPES = frozenset({"<f4", "<f8", "<i4", "<i8", "|u1", "|b1", "<f2", "<u4"})


class WireError(ValueError):
    """A message that cannot be decoded: names the field or frame and what was expected."""

    def __init__(self, reason: str, kind: str = "malformed"):
        super().__init__(reason)
        self.kind = kind
        """Counter bucket: malformed | version | unknown_kind | oversized | bad_array | nonfinite."""


# --------------------------------------------------------------------------------------------
# Messages. Bump `VERSION` on a message when its fields change meaning or shape.


@dataclass(frozen=True)
class UnrollMsg:
    """T control steps of N environments from one rollout actor (actor -> learner, PUSH).

    Arrays are time-major `[T, N, ...]`. `next_obs[t]` is the observation after step t *before*
    any reset, so a truncated episode can be bootstrapped from its true last state.
    """

    KIND: ClassVar[str] = "unroll"
    VERSION: ClassVar[int] = 1
    actor_id: int
    seq: int
    """Per-actor sequence number, +1 per unroll; gaps mean lost unrolls."""
    policy_version: int
    """Version of the weights that chose these actions."""
    obs: np.ndarray  # [T, N, obs_dim] float32, raw (not normalized)
    next_obs: np.ndarray  # [T, N, obs_dim] float32
    actions: np.ndarray  # [T, N, act_dim] float32, pre-squash Gaussian samples
    logp: np.ndarray  # [T, N] float32, behaviour log-probability of `actions`
    rewards: np.ndarray  # [T, N] float32
    terminated: np.ndarray  # [T, N] bool: no bootstrap (fall, task end)
    truncated: np.ndarray  # [T, N] bool: bootstrap from next_obs (time limit, divergence)
    params: np.ndarray  # [T, N, n_params] float32: the episode's sampled task/shape parameters
    episode_returns: list[float] = field(default_factory=list)
    """Undiscounted returns of the episodes that ended inside this unroll."""
    episode_lengths: list[int] = field(default_factory=list)
    divergences: int = 0
    """Episodes truncated in this unroll because MuJoCo reported a divergence warning."""
    sampler_outages: int = 0
    """Draws that fell back to the previous parameters because the sampler did not answer."""


@dataclass(frozen=True)
class WeightsMsg:
    """Policy weights and observation-normalizer statistics (learner -> actors, PUB or reply)."""

    KIND: ClassVar[str] = "weights"
    VERSION: ClassVar[int] = 1
    policy_version: int
    tensors: dict[str, np.ndarray]
    """The actor-side state dict (policy mean network, log-std, normalizer buffers)."""


@dataclass(frozen=True)
class WeightsRequestMsg:
    """An actor asks for the current weights on (re)connect: PUB drops slow joiners."""

    KIND: ClassVar[str] = "weights_request"
    VERSION: ClassVar[int] = 1
    actor_id: int
    have_version: int = -1


@dataclass(frozen=True)
class HeartbeatMsg:
    """An actor is alive (actor -> learner over the unroll channel)."""

    KIND: ClassVar[str] = "heartbeat"
    VERSION: ClassVar[int] = 1
    actor_id: int
    seq: int
    """The sequence number of the last unroll sent."""
    env_steps: int


@dataclass(frozen=True)
class DrawRequestMsg:
    """Ask the sampler for `n` episode parameter draws."""

    KIND: ClassVar[str] = "draw_request"
    VERSION: ClassVar[int] = 1
    n: int
    client_id: int = 0


@dataclass(frozen=True)
class DrawReplyMsg:
    """`n` episode draws: task/shape parameter vectors and motion clip ids."""

    KIND: ClassVar[str] = "draw_reply"
    VERSION: ClassVar[int] = 1
    params: np.ndarray  # [n, n_params] float32 in the task's parameter order
    clip_ids: list[str] = field(default_factory=list)
    """One clip id per draw, or empty when the task uses no motion clips."""
    buffer_generation: int = 0
    """How many MCMC refills have happened: lets a client see stale draws."""


@dataclass(frozen=True)
class ValueReportMsg:
    """`(parameters, V(s))` pairs for the marginal value fit (Won & Lee 2019, Alg. 1)."""

    KIND: ClassVar[str] = "value_report"
    VERSION: ClassVar[int] = 1
    params: np.ndarray  # [m, n_params] float32
    values: np.ndarray  # [m] float32


@dataclass(frozen=True)
class TickMsg:
    """One policy iteration has finished (learner -> sampler); may trigger an MCMC refill."""

    KIND: ClassVar[str] = "tick"
    VERSION: ClassVar[int] = 1
    iteration: int


@dataclass(frozen=True)
class StatsRequestMsg:
    KIND: ClassVar[str] = "stats_request"
    VERSION: ClassVar[int] = 1


@dataclass(frozen=True)
class StatsReplyMsg:
    """Flat metric name -> number, logged by the learner under `sampler/`."""

    KIND: ClassVar[str] = "stats_reply"
    VERSION: ClassVar[int] = 1
    stats: dict[str, float]


@dataclass(frozen=True)
class StateRequestMsg:
    """Ask the sampler for its whole state (it goes into the learner's checkpoint)."""

    KIND: ClassVar[str] = "state_request"
    VERSION: ClassVar[int] = 1


@dataclass(frozen=True)
class StateMsg:
    """A service's state: primitives in `meta`, arrays in `arrays` (checkpointable as is)."""

    KIND: ClassVar[str] = "state"
    VERSION: ClassVar[int] = 1
    meta: dict[str, Any]
    arrays: dict[str, np.ndarray]


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
    error_kind: str = "malformed"


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
# Codec


def _field_kinds(cls: type) -> dict[str, str]:
    """Map each field of a message class to 'array', 'array_dict' or 'plain'."""
    cached = getattr(cls, "_wire_field_kinds", None)
    if cached is not None:
        return cached
    hints = typing.get_type_hints(cls)
    kinds: dict[str, str] = {}
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        if hint is np.ndarray:
            kinds[f.name] = "array"
        elif typing.get_origin(hint) is dict and typing.get_args(hint)[1] is np.ndarray:
            kinds[f.name] = "array_dict"
        else:
            kinds[f.name] = "plain"
    type.__setattr__(cls, "_wire_field_kinds", kinds)
    return kinds


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


def _nbytes(frame: Any) -> int:
    return frame.nbytes if isinstance(frame, memoryview) else len(frame)


def decode(frames: list[Any], expect: type | tuple[type, ...] | None = None) -> Any:
    """Decode multipart frames into a message; raise `WireError` on anything malformed.

    `frames` may be bytes, memoryviews or zmq.Frame objects (their `.buffer` is used).
    `expect` restricts which message classes are acceptable here.
    """
    bufs = [f.buffer if hasattr(f, "buffer") else f for f in frames]
    if not bufs:
        raise WireError("empty message: expected a msgpack header frame")
    total = sum(_nbytes(b) for b in bufs)
    if total > MAX_MESSAGE_BYTES:
        raise WireError(f"message of {total} bytes exceeds the limit of {MAX_MESSAGE_BYTES}", "oversized")
    try:
        header = msgpack.unpackb(bytes(bufs[0]), raw=False, strict_map_key=True, max_bin_len=0, max_ext_len=0)
    except Exception as exc:  # msgpack raises several unrelated types
        raise WireError(f"header is not valid msgpack ({type(exc).__name__}: {exc})") from None
    if not isinstance(header, dict) or header.get("p") != PROTOCOL:
        got = header.get("p") if isinstance(header, dict) else type(header).__name__
        raise WireError(f"protocol {got!r} is not {PROTOCOL!r}", "version")
    kind, version = header.get("k"), header.get("v")
    cls = MESSAGES.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise WireError(f"unknown message kind {kind!r}; known: {sorted(MESSAGES)}", "unknown_kind")
    if version != cls.VERSION:
        raise WireError(f"{kind} version {version!r} is not the supported {cls.VERSION}", "version")
    if expect is not None and not issubclass(cls, expect):
        raise WireError(f"message kind {kind!r} is not accepted on this socket", "unknown_kind")
    plain, specs = header.get("f"), header.get("a")
    if not isinstance(plain, dict) or not isinstance(specs, list):
        raise WireError(f"{kind} header lacks its field map or array list")
    if len(specs) != len(bufs) - 1:
        raise WireError(f"{kind} declares {len(specs)} arrays but carries {len(bufs) - 1} frames (truncated?)")

    arrays: dict[str, np.ndarray] = {}
    for spec, buf in zip(specs, bufs[1:]):
        try:
            name, dtype, shape = spec
            shape = tuple(int(s) for s in shape)
        except (TypeError, ValueError):
            raise WireError(f"{kind} has a malformed array spec {spec!r}", "bad_array") from None
        if dtype not in ALLOWED_DTYPES or any(s < 0 for s in shape):
            raise WireError(f"{kind} array {name!r}: dtype {dtype!r} shape {shape} not allowed", "bad_array")
        expected = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
        if _nbytes(buf) != expected:
            raise WireError(
                f"{kind} array {name!r}: {_nbytes(buf)} bytes for shape {shape} {dtype} (expected {expected})",
                "bad_array",
            )
        arrays[name] = np.frombuffer(buf, dtype=dtype).reshape(shape) if expected else np.zeros(shape, dtype)

    values: dict[str, Any] = {}
    for name, fkind in _field_kinds(cls).items():
        if fkind == "array":
            if name not in arrays:
                raise WireError(f"{kind} lacks array field {name!r}", "bad_array")
            values[name] = arrays[name]
        elif fkind == "array_dict":
            keys = plain.get(name)
            if not isinstance(keys, list) or any(f"{name}/{k}" not in arrays for k in keys):
                raise WireError(f"{kind} array map {name!r} does not match its frames", "bad_array")
            values[name] = {k: arrays[f"{name}/{k}"] for k in keys}
        elif name in plain:
            values[name] = plain[name]
    try:
        return cls(**values)
    except TypeError as exc:
        raise WireError(f"{kind} fields do not match: {exc}") from None


def check_finite(msg: Any) -> None:
    """Raise `WireError('nonfinite')` if any float array of `msg` holds NaN or Inf."""
    for name, kind in _field_kinds(type(msg)).items():
        value = getattr(msg, name)
        items = value.items() if kind == "array_dict" else [(name, value)] if kind == "array" else []
        for key, arr in items:
            if arr.dtype.kind == "f" and not np.isfinite(arr).all():
                raise WireError(f"{type(msg).KIND} array {key!r} holds NaN or Inf", "nonfinite")
