"""`morphmimic bench learner`: the PPO update's cost per minibatch step, old path against new.

For each preset: its policy and value networks (hidden sizes, observation and action sizes of
its task), its PPO settings (epochs, minibatch, transitions per update) and one batch of random
transitions with actions drawn from the policy. Two identical copies start each round from the
same state; `learner.ppo_reference.reference_update` (the textbook loop the update was first
written as) and `PPO.update` run on the same batch with the same minibatch order, interleaved
(old, new, old, new, ...), so background load hits both alike. Reported: milliseconds per
minibatch step of each (median over rounds, and the fastest round, the least disturbed by other
load), their ratio per round (median, min-max) and of the fastest rounds, and the largest
parameter difference after one update (0 today: the same maths in the same order).

Torch runs single-threaded by default, as the learner does when the actors take the other cores.
"""

from __future__ import annotations

import copy
import dataclasses
import statistics
import time
from dataclasses import dataclass
from typing import Annotated, ClassVar

import torch
from tyro.constructors import PrimitiveConstructorSpec

from common.config_limits import Limit, between, check_limits, validated
from common.policy import GaussianPolicy, ValueNet
from common.tasks.registry import make_env
from learner.cli_options import CommaStrs, parse_options
from learner.ppo import PPO, Batch
from learner.ppo_reference import reference_update
from learner.presets import PRESETS, check_presets


def random_batch(policy: GaussianPolicy, steps: int, unroll: int, seed: int) -> Batch:
    """`steps` transitions as `[unroll, steps / unroll]`; observations with a spread of scales
    (as the normalizer meets them), actions and log-probabilities from the policy itself."""
    g = torch.Generator().manual_seed(seed)
    T, B = unroll, steps // unroll
    scale = torch.rand(policy.obs_dim, generator=g) * 5
    offset = torch.randn(policy.obs_dim, generator=g)
    obs = offset + scale * torch.randn(T, B, policy.obs_dim, generator=g)
    next_obs = offset + scale * torch.randn(T, B, policy.obs_dim, generator=g)
    with torch.no_grad():
        policy.normalizer.update(obs.reshape(-1, policy.obs_dim))
        dist = policy.distribution(obs)
        actions = dist.mean + dist.stddev * torch.randn(dist.mean.shape, generator=g)
        logp = dist.log_prob(actions).sum(-1)
    policy.normalizer.count.zero_()
    policy.normalizer.mean.zero_()
    policy.normalizer.var.fill_(1.0)
    terminated = torch.rand(T, B, generator=g) < 0.03
    truncated = (torch.rand(T, B, generator=g) < 0.01) & ~terminated
    return Batch(obs, next_obs, actions, logp, torch.rand(T, B, generator=g) * 2, terminated, truncated)


@torch.no_grad()
def _max_param_diff(a: PPO, b: PPO) -> float:
    pa = [*a.policy.parameters(), *a.value.parameters()]
    pb = [*b.policy.parameters(), *b.value.parameters()]
    return max(float((x - y).abs().max()) for x, y in zip(pa, pb))


def _start(preset: str, seed: int):
    """(run config, fresh policy, value net, one batch of random transitions) of a preset."""
    cfg = PRESETS[preset][1]
    env = make_env(cfg.task, seed=0)
    obs_dim, act_dim = env.obs_dim, env.act_dim
    del env
    torch.manual_seed(seed)
    policy, value = GaussianPolicy(obs_dim, act_dim, cfg.policy), ValueNet(obs_dim, cfg.policy)
    return cfg, policy, value, random_batch(policy, cfg.steps_per_iteration, cfg.actors.unroll_length, seed)


def measure(preset: str, rounds: int, seed: int = 0) -> dict[str, object]:
    cfg, policy, value, batch = _start(preset, seed)
    obs_dim, act_dim = policy.obs_dim, policy.act_dim
    start = PPO(policy, value, cfg.ppo)
    runners = {"old": lambda p, g: reference_update(p, batch, g), "new": lambda p, g: p.update(batch, g)}
    per_step: dict[str, list[float]] = {"old": [], "new": []}
    ratios: list[float] = []
    diff = float("nan")
    for r in range(rounds + 1):  # round 0 warms both paths up and is not timed
        ran = {}
        for name in (("old", "new") if r % 2 else ("new", "old")):
            ppo = copy.deepcopy(start)
            gen = torch.Generator().manual_seed(seed + r)
            t0 = time.perf_counter()
            metrics = runners[name](ppo, gen)
            dt = time.perf_counter() - t0
            ran[name] = (ppo, dt / max(metrics["minibatch_steps"], 1.0))
        if r == 0:
            diff = _max_param_diff(ran["old"][0], ran["new"][0])
            continue
        for name in ran:
            per_step[name].append(ran[name][1])
        ratios.append(ran["old"][1] / ran["new"][1])
    return {
        "preset": preset, "obs_dim": obs_dim, "act_dim": act_dim, "hidden": cfg.policy.hidden,
        "epochs": cfg.ppo.epochs, "minibatch": cfg.ppo.minibatch, "steps": cfg.steps_per_iteration,
        "old_ms": 1e3 * statistics.median(per_step["old"]), "new_ms": 1e3 * statistics.median(per_step["new"]),
        "old_best_ms": 1e3 * min(per_step["old"]), "new_best_ms": 1e3 * min(per_step["new"]),
        "ratio": statistics.median(ratios), "ratio_min": min(ratios), "ratio_max": max(ratios), "max_param_diff": diff,
    }


def parse_schedules(text: str) -> list[tuple[int, int]]:
    """"10x128,10x512" -> [(10, 128), (10, 512)]: epochs x minibatch per PPO update, epochs 1-100
    and minibatch 1-65536; ValueError naming the first item that is not one."""
    out = []
    for item in text.split(","):
        try:
            epochs, minibatch = (int(x) for x in item.strip().lower().split("x"))
        except ValueError:
            raise ValueError(f"{item!r}: give EPOCHSxMINIBATCH, e.g. 10x128") from None
        if not (1 <= epochs <= 100 and 1 <= minibatch <= 65536):
            raise ValueError(f"{item!r}: epochs 1-100 and minibatch 1-65536")
        out.append((epochs, minibatch))
    return out


SCHEDULES = PrimitiveConstructorSpec(
    nargs=1, metavar="EPOCHSxMINIBATCH,...", instance_from_str=lambda args: tuple(parse_schedules(args[0])),
    is_instance=lambda v: isinstance(v, tuple), str_from_instance=lambda v: [",".join(f"{e}x{m}" for e, m in v or ())])
"""`--schedules 10x128,10x512` as a tuple of (epochs, minibatch)."""


def measure_schedules(preset: str, schedules: list[tuple[int, int]], rounds: int, seed: int = 0) -> list[dict]:
    """Wall time of one whole `PPO.update` per epochs x minibatch schedule, on the same batch
    and start, interleaved (the order reversed every other round), the KL stop off so every
    schedule does all its epochs: the learner's cost per collected sample under each."""
    cfg, policy, value, batch = _start(preset, seed)
    times: dict[tuple[int, int], list[float]] = {s: [] for s in schedules}
    for r in range(rounds + 1):  # round 0 warms up and is not timed
        for sched in (schedules if r % 2 else schedules[::-1]):
            ppo = PPO(copy.deepcopy(policy), copy.deepcopy(value),
                      dataclasses.replace(cfg.ppo, epochs=sched[0], minibatch=sched[1], kl_stop=0.0))
            t0 = time.perf_counter()
            ppo.update(batch, torch.Generator().manual_seed(seed + r))
            if r:
                times[sched].append(time.perf_counter() - t0)
    first = statistics.median(times[schedules[0]])
    return [{"epochs": e, "minibatch": m, "update_s": statistics.median(times[(e, m)]),
             "us_per_sample": 1e6 * statistics.median(times[(e, m)]) / cfg.steps_per_iteration,
             "speedup_vs_first": first / statistics.median(times[(e, m)])} for e, m in schedules]


PROG = "morphmimic bench learner"


@validated
@dataclass
class LearnerBenchOptions:
    presets: CommaStrs = ("lower_biped", "executor")
    """Comma-separated training presets."""
    rounds: int = 10
    """Timed rounds, each one old and one new update."""
    threads: int = 1
    """Torch threads (the learner's, next to the actors)."""
    schedules: Annotated[tuple[tuple[int, int], ...] | None, SCHEDULES] = None
    """Instead: whole updates under these epochs x minibatch schedules, e.g. 10x128,10x512,5x256 (the
    first is the reference of the ratios)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"rounds": between(1, 1000, integer=True), "threads": between(1, 256, integer=True)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_presets("--presets", self.presets)
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(LearnerBenchOptions, argv, prog=PROG, description=__doc__)
    torch.set_num_threads(args.threads)
    if args.schedules:
        for preset in args.presets:
            rows = measure_schedules(preset, list(args.schedules), args.rounds)
            print(f"{preset}: one PPO update per schedule, {args.threads} thread(s), {args.rounds} rounds, KL stop off")
            for x in rows:
                print(f"  {x['epochs']:3d} epochs x {x['minibatch']:5d}  {1e3 * x['update_s']:8.1f} ms per update  "
                      f"{x['us_per_sample']:7.1f} us per sample  {x['speedup_vs_first']:5.2f}x the first's speed")
        return 0
    for preset in args.presets:
        m = measure(preset, args.rounds)
        print(f"{m['preset']}: obs {m['obs_dim']}, act {m['act_dim']}, hidden {m['hidden']}, "
              f"{m['epochs']} epochs x {m['minibatch']} of {m['steps']} per update, {args.threads} thread(s), {args.rounds} rounds")
        print(f"  old update (reference loop)   {m['old_ms']:7.2f} ms per minibatch step (fastest round {m['old_best_ms']:.2f})")
        print(f"  new update (PPO.update)       {m['new_ms']:7.2f} ms per minibatch step (fastest round {m['new_best_ms']:.2f})")
        print(f"  speed-up old / new            {m['ratio']:7.2f}  median of rounds ({m['ratio_min']:.2f}-{m['ratio_max']:.2f}); "
              f"fastest rounds {m['old_best_ms'] / m['new_best_ms']:.2f}")
        print(f"  largest parameter difference after one update  {m['max_param_diff']:.1e}")
    return 0
