"""A shape task's control step three ways, per preset: `ShapeBatch` (N environments as one batch),
N single `ImitateEnv`s stepped one after another (what a `LoopBatch` does) and the pure physics
of the same N models (`mj_step` x substeps, nothing else).

`morphmimic bench shape-batch [--presets lower_biped,fish] [--n 8] [--steps 600] [--rounds 4]`

Each round builds the batch and N single environments with the same seeds, resets them on the
same random shapes, then times `--steps` control steps of each way on the same seeded actions
(small, so walkers stay up for a while; ended episodes are reset outside the timing), the order
of the three ways alternating between rounds so background load hits all alike. Reported per
preset: the median over rounds of milliseconds per batch step for each way and the ratios
batch / physics, loop / physics and loop / batch.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import ClassVar

import mujoco
import numpy as np

from common.config_limits import Limit, at_least, check_limits, validated
from common.tasks.shape.batch import ShapeBatch
from common.tasks.shape.env import ImitateEnv
from common.tasks.shape.presets import SHAPE_TASKS, shape_task
from learner.cli_options import CommaStrs, parse_options


def _time_batch(batch: ShapeBatch, actions: np.ndarray, shapes: np.ndarray) -> float:
    total = 0.0
    for a in actions:
        t0 = time.perf_counter()
        _, _, term, trunc, _ = batch.step(a)
        total += time.perf_counter() - t0
        for i in np.flatnonzero(term | trunc):
            batch.reset_one(int(i), None, shapes[i])
    return total / len(actions)


def _time_loop(envs: list[ImitateEnv], actions: np.ndarray, shapes: np.ndarray) -> float:
    total = 0.0
    for a in actions:
        t0 = time.perf_counter()
        ends = [env.step(a[i])[2:4] for i, env in enumerate(envs)]
        total += time.perf_counter() - t0
        for i, (term, trunc) in enumerate(ends):
            if term or trunc:
                envs[i].reset(None, shapes[i])
    return total / len(actions)


def _time_physics(envs: list[ImitateEnv], steps: int, substeps: int) -> float:
    pairs = []
    for env in envs:
        data = mujoco.MjData(env.model)
        data.qpos[:], data.qvel[:], data.ctrl[:] = env.data.qpos, env.data.qvel, env.ref_joints[1]
        mujoco.mj_forward(env.model, data)
        pairs.append((env.model, data))
    t0 = time.perf_counter()
    for _ in range(steps):
        for model, data in pairs:
            mujoco.mj_step(model, data, nstep=substeps)
    return (time.perf_counter() - t0) / steps


def bench(preset: str, n: int, steps: int, round_: int) -> dict[str, float]:
    cfg = shape_task(preset)
    seeds = [round_ * 1000 + i for i in range(n)]
    batch, envs = ShapeBatch(cfg, seeds), [ImitateEnv(cfg, s) for s in seeds]
    rng = np.random.default_rng(round_)
    shapes = batch.space.uniform(rng, n)
    for i in range(n):
        batch.reset_one(i, seeds[i], shapes[i])
        envs[i].reset(seeds[i], shapes[i])
    actions = rng.normal(0.0, 0.05, (steps, n, batch.act_dim))
    ways = {"batch": lambda: _time_batch(batch, actions, shapes), "loop": lambda: _time_loop(envs, actions, shapes),
            "physics": lambda: _time_physics(envs, steps, cfg.substeps)}
    order = list(ways)[round_ % 3:] + list(ways)[: round_ % 3]
    return {name: ways[name]() for name in order}


@validated
@dataclass
class ShapeBatchBenchOptions:
    presets: CommaStrs = ("lower_biped", "fish")
    """Comma-separated shape tasks."""
    n: int = 8
    """Environments per batch (the shape presets' envs_per_actor is 8)."""
    steps: int = 600
    """Control steps timed per way and round."""
    rounds: int = 4
    """Rounds per preset (the order of the three ways alternates)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"n": at_least(1), "steps": at_least(1), "rounds": at_least(1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        unknown = [t for t in self.presets if t not in SHAPE_TASKS]
        if unknown:
            raise ValueError(f"unknown shape task(s) {unknown}; choose from {', '.join(SHAPE_TASKS)}")
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(ShapeBatchBenchOptions, argv, prog="morphmimic bench shape-batch", description=__doc__.split("\n\n")[0])
    for preset in args.presets:
        runs = [bench(preset, args.n, args.steps, r) for r in range(args.rounds)]
        ms = {k: 1e3 * statistics.median(run[k] for run in runs) for k in runs[0]}
        ratio = {k: statistics.median(run[a] / run[b] for run in runs)
                 for k, (a, b) in {"batch/physics": ("batch", "physics"), "loop/physics": ("loop", "physics"),
                                   "loop/batch": ("loop", "batch")}.items()}
        print(f"{preset} N={args.n}: ms per step batch {ms['batch']:.2f} loop {ms['loop']:.2f} physics {ms['physics']:.2f}; "
              + ", ".join(f"{k} {v:.2f}" for k, v in ratio.items()))
    return 0
