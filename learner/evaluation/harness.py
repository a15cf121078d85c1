"""What every evaluation runs on, whatever its task: the task as evaluated (`eval_task`), the
zero-action baseline (`ZeroPolicy`), a pool of processes running episodes (`run_jobs`), the
ablation commands' outputs (`write_ablation`) and two helpers of their options (`one_value`,
`changed_flags`)."""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import signal
from pathlib import Path
from typing import Any, Callable

import numpy as np
from tyro.constructors import PrimitiveConstructorSpec

from common.config_limits import flag
from common.tasks.base import TaskConfig


def one_value(parse: Callable[[str], tuple], metavar: str, show: Callable[[tuple], str]) -> PrimitiveConstructorSpec:
    """A flag taking one value that `parse` reads as a tuple (`--rows speed,mass`, `--schedule
    '[[0, {}], ...]'`); the message of the ValueError `parse` raises is the parse error, so it
    should name the value and what is allowed. `show` writes a value back (the default in --help)."""
    return PrimitiveConstructorSpec(nargs=1, metavar=metavar, instance_from_str=lambda args: parse(args[0]),
                                    is_instance=lambda v: isinstance(v, tuple), str_from_instance=lambda v: [show(v)])


def changed_flags(opts: Any, names: tuple[str, ...], flags: dict[str, str] | None = None) -> list[str]:
    """The flags of the fields `names` of the options dataclass `opts` that hold other values than
    their defaults (options given that do not apply), each `--field-name` unless `flags` names it."""
    defaults = {f.name: f.default for f in dataclasses.fields(opts)}
    return [(flags or {}).get(n) or flag("", n) for n in names if getattr(opts, n) != defaults[n]]


def check_box_scale(box_scale: float) -> float:
    """`box_scale` if it is in (0, 1], else ValueError naming it and the range."""
    if not 0.0 < box_scale <= 1.0:
        raise ValueError(f"box scale {box_scale:g} must be in (0, 1] (1: the whole box, the paper's protocol)")
    return box_scale


def eval_task(cfg: TaskConfig, episode_s: float, box_scale: float = 1.0) -> TaskConfig:
    """The task as evaluated: every shape of the parameterization (even for a checkpoint trained
    on one shape or a shrunken box), a fixed start at phase 0, the given horizon. `box_scale` < 1
    evaluates on the box shrunk toward the base shape instead (a curriculum's progress; not the
    paper's protocol)."""
    check_box_scale(box_scale)
    return dataclasses.replace(cfg, episode_s=episode_s,
                               body=dataclasses.replace(cfg.body, vary_shape=True, shape_box_scale=box_scale),
                               imitate=dataclasses.replace(cfg.imitate, random_start_phase=False))


class ZeroPolicy:
    """Acts with zero actions, the baseline a trained policy is measured against: for a PD task
    the character's PD on the reference itself (a zero deviation from the target pose), for a
    torque task no torque."""

    def __init__(self, act_dim: int) -> None:
        self.act_dim = int(act_dim)

    def act(self, obs_raw: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, np.ndarray]:
        n = len(obs_raw)
        return np.zeros((n, self.act_dim), np.float32), np.zeros(n, np.float32)


def _init_pool_worker(init: Callable, init_args: tuple) -> None:
    """A forked pool worker's set-up: the default signal dispositions first (a worker inherits
    the parent's Python handlers, such as the one `ray.init` installs that raises SystemExit on
    SIGTERM, and then survives the pool's SIGTERM at its end, hanging the pool's join for good;
    Ctrl-C is the parent's to handle), then `init(*init_args)`."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    init(*init_args)


def run_jobs(init: Callable, init_args: tuple, work: Callable[[Any], dict], jobs: list, workers: int,
             progress: Callable[[int, int], None] | None = None) -> list[dict]:
    """`work(job)` for every job, in this process (`workers` <= 1) or in a pool of forked
    processes each set up once by `init(*init_args)`; results (dicts with an "index") sorted by
    their index. `progress(done, total)` is called after each job."""
    results: list[dict] = []
    if workers <= 1:
        init(*init_args)
        for job in jobs:
            results.append(work(job))
            if progress:
                progress(len(results), len(jobs))
    else:
        ctx = multiprocessing.get_context("fork")
        with ctx.Pool(min(workers, len(jobs)), initializer=_init_pool_worker,
                      initargs=(init, init_args)) as pool:
            for res in pool.imap_unordered(work, jobs):
                results.append(res)
                if progress:
                    progress(len(results), len(jobs))
    return sorted(results, key=lambda r: r["index"])


def write_ablation(out: Path, text: str, arms: list[dict[str, Any]]) -> None:
    """An ablation command's outputs: the markdown table `out/ablation.md`, one JSON entry per
    arm in `out/ablation.json`, and the table printed."""
    (out / "ablation.md").write_text(text)
    (out / "ablation.json").write_text(json.dumps(arms, indent=1) + "\n")
    print(text)
