"""`morphmimic bench episodes`: what a new body costs against a control step, per shape task.

Won & Lee 2019 draw a new body shape for every episode (METHOD.md A), so each reset builds a
character and retargets the clip onto it; while the policy is young, episodes are short (30-50
control steps) and that reset cost is a large share of collection. In one run, per task:
- reset: `ImitateEnv.reset` on a fresh random shape (character build, retargeting, first state);
- step: `ImitateEnv.step` with small random actions (physics, state, reward; episodes that end
  are restarted on the same shape, a cached reset that is not counted);
- the ratio reset / step, and the share of environment time the resets take at two episode
  lengths. Absolute times swing between runs on a shared machine: read the ratio.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Annotated, ClassVar

import numpy as np

from common.config_limits import SEED, Limit, at_least, check_limits, validated
from learner.cli_options import CommaStrs, comma_list, parse_options


SHAPE_TASKS = ("lower_biped", "quadruped", "biped", "fish", "manta")


def bench_task(name: str, resets: int, steps: int, seed: int) -> dict[str, float]:
    from common.tasks.registry import make_env  # lazy: start-up time of morphmimic bench episodes --help (mujoco)
    from learner.presets import PRESETS  # lazy: start-up time of morphmimic bench episodes --help (torch)

    env = make_env(PRESETS[name][1].task, seed=seed)
    rng = np.random.default_rng(seed)
    shapes = env.space.uniform(rng, resets + 1)
    env.reset(None, shapes[-1])  # warm-up: clip preparation and contact phases are per process
    start = time.perf_counter()
    for shape in shapes[:resets]:
        env.reset(None, shape)
    reset_s = (time.perf_counter() - start) / resets
    step_s, done = 0.0, 0
    while done < steps:
        start = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(rng.normal(0.0, 0.3, env.act_dim))
        step_s += time.perf_counter() - start
        done += 1
        if terminated or truncated:
            env.reset(None, shapes[0])
    return {"reset_ms": reset_s * 1e3, "step_ms": step_s / steps * 1e3}


@validated
@dataclass
class EpisodeBenchOptions:
    tasks: CommaStrs = SHAPE_TASKS
    """Comma-separated shape tasks."""
    resets: int = 30
    """Resets on fresh random shapes per task."""
    steps: int = 600
    """Control steps timed per task."""
    lengths: Annotated[tuple[int, ...], comma_list(int, "40,900", "two positive episode lengths")] = (40, 900)
    """Two episode lengths (control steps) for the reset share."""
    seed: int = 0
    """Seed of the shapes and actions."""

    LIMITS: ClassVar[dict[str, Limit]] = {"resets": at_least(1), "steps": at_least(1), "lengths": at_least(1),
                                          "seed": SEED}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        unknown = [t for t in self.tasks if t not in SHAPE_TASKS]
        if unknown:
            raise ValueError(f"unknown task(s) {unknown}; choose from {', '.join(SHAPE_TASKS)}")
        if len(self.lengths) != 2:
            raise ValueError(f"--lengths {','.join(map(str, self.lengths))}: give two positive episode lengths, e.g. 40,900")
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(EpisodeBenchOptions, argv, prog="morphmimic bench episodes", description=__doc__.split("\n\n")[0])
    tasks, lengths = args.tasks, args.lengths
    header = (f"{'task':<12} {'reset (new shape)':>17} {'control step':>12} {'reset/step':>10} "
              f"{f'share at {lengths[0]}':>12} {f'share at {lengths[1]}':>12}")
    print(header)
    print("-" * len(header))
    for task in tasks:
        r = bench_task(task, args.resets, args.steps, args.seed)
        ratio = r["reset_ms"] / r["step_ms"]
        shares = [ratio / (ratio + n) for n in lengths]
        print(f"{task:<12} {r['reset_ms']:>14.1f} ms {r['step_ms']:>9.2f} ms {ratio:>10.1f} "
              f"{shares[0]:>11.0%} {shares[1]:>12.0%}")
    return 0
