"""`morphmimic bench curve`: what CURVE authentication and encryption cost on the wire.

Two things in one run, interleaved round by round so that both see the same machine: the unroll
stream (an actor's PUSH to the learner's PULL on 127.0.0.1, messages shaped like a preset's
unrolls) and a sampler-sized request/reply round trip (DEALER to ROUTER), each once over plain
sockets and once with the run's CURVE keys (`common.curve_keys`). Prints MB/s and round trips per
second for both and their ratio; the end-to-end effect on training is
`morphmimic bench throughput` against `morphmimic bench throughput --no-curve`.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import zmq

from common import sockets, wire
from common.config_limits import Limit, at_least, check_limits, validated
from common.curve_keys import LEARNER, RunKeys
from common.tasks.registry import make_env
from learner.cli_options import parse_options
from learner.presets import PRESETS, check_presets


def _unroll(T: int, N: int, obs_dim: int, act_dim: int, n_params: int) -> list:
    rng = np.random.default_rng(0)
    f = lambda *s: rng.standard_normal(s).astype(np.float32)  # noqa: E731
    msg = wire.UnrollMsg(actor_id=0, seq=0, policy_version=0, obs=f(T, N, obs_dim), next_obs=f(T, N, obs_dim),
                         actions=f(T, N, act_dim), logp=f(T, N), rewards=f(T, N), terminated=np.zeros((T, N), bool),
                         truncated=np.zeros((T, N), bool), params=f(T, N, n_params))
    return [bytes(x) for x in wire.encode(msg)]


def stream(frames: list, messages: int, keys: RunKeys | None) -> float:
    """Seconds to push `messages` copies of `frames` through PUSH -> PULL on 127.0.0.1."""
    pull, endpoint = sockets.bind_unroll_pull("tcp://127.0.0.1", keys)
    push = sockets.connect_unroll_push(endpoint, keys.for_actor(0) if keys else None)
    try:
        push.send_multipart(frames)
        pull.recv_multipart()  # the handshake is done
        t0 = time.perf_counter()
        for _ in range(messages):
            push.send_multipart(frames, copy=False)
            pull.recv_multipart(copy=False)
        return time.perf_counter() - t0
    finally:
        push.close(linger=0)
        pull.close(linger=0)


def round_trips(request: list, reply: list, n: int, keys: RunKeys | None) -> float:
    """Seconds for `n` request/reply round trips DEALER -> ROUTER on 127.0.0.1."""
    router, endpoint = sockets.bind_router("tcp://127.0.0.1", keys)
    dealer = sockets.connect_dealer(endpoint, keys, LEARNER)
    try:
        t0 = None
        for i in range(n + 1):
            if i == 1:
                t0 = time.perf_counter()
            dealer.send_multipart([b"", *request])
            ident, _, *_body = router.recv_multipart()
            router.send_multipart([ident, b"", *reply])
            dealer.recv_multipart()
        return time.perf_counter() - t0
    finally:
        dealer.close(linger=0)
        router.close(linger=0)


PROG = "morphmimic bench curve"


@validated
@dataclass
class CurveBenchOptions:
    preset: str = "executor"
    """Preset whose unroll shape is streamed."""
    obs_dim: int = 0
    """Observation size (0: the preset's task)."""
    messages: int = 200
    """Unrolls per round and mode."""
    round_trips: int = 2000
    """Request/reply pairs per round and mode."""
    rounds: int = 5
    """Timed rounds."""

    LIMITS: ClassVar[dict[str, Limit]] = {"obs_dim": at_least(0), "messages": at_least(1), "round_trips": at_least(1), "rounds": at_least(1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_presets("--preset", [self.preset])
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(CurveBenchOptions, argv, prog=PROG, description=__doc__)
    cfg = PRESETS[args.preset][1]
    obs_dim, act_dim, n_params = args.obs_dim, 2, 1
    if not obs_dim:
        env = make_env(cfg.task, seed=0)
        obs_dim, act_dim, n_params = env.obs_dim, env.act_dim, env.space.dim
    T, N = cfg.actors.unroll_length, cfg.actors.envs_per_actor
    frames = _unroll(T, N, obs_dim, act_dim, n_params)
    size = sum(len(f) for f in frames)
    request = [bytes(x) for x in wire.encode(wire.DrawRequestMsg(n=32, client_id=0))]
    reply = [bytes(x) for x in wire.encode(wire.DrawReplyMsg(params=np.zeros((32, n_params), np.float32),
                                                             clip_ids=["humanoid3d_walk"] * 32, buffer_generation=1))]
    keys = RunKeys.generate()
    mb = {"plain": [], "curve": []}
    rt = {"plain": [], "curve": []}
    for _ in range(args.rounds):
        for mode, k in (("plain", None), ("curve", keys)):
            mb[mode].append(args.messages * size / stream(frames, args.messages, k) / 1e6)
            rt[mode].append(args.round_trips / round_trips(request, reply, args.round_trips, k))
    med = statistics.median
    print(f"unrolls of {args.preset} ({T} x {N} x obs {obs_dim}): {size / 1e3:.0f} kB each, {args.rounds} rounds, "
          f"{zmq.zmq_version()} libzmq")
    print(f"  unroll stream   plain {med(mb['plain']):8.0f} MB/s   CURVE {med(mb['curve']):8.0f} MB/s   "
          f"ratio {med(mb['curve']) / med(mb['plain']):.2f}")
    print(f"  round trips     plain {med(rt['plain']):8.0f} /s     CURVE {med(rt['curve']):8.0f} /s     "
          f"ratio {med(rt['curve']) / med(rt['plain']):.2f}")
    print(f"  per round, stream ratio  {' '.join(f'{c / p:.2f}' for c, p in zip(mb['curve'], mb['plain']))}")
    return 0
