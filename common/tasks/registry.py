"""One registry of tasks: `make_env(cfg, seed)` and `task_space(cfg)` by task name."""

from __future__ import annotations

import importlib

from common.params import ParamSpace
from common.tasks.base import Env, TaskConfig

TASKS: dict[str, str] = {
    "reach": "common.tasks.reach:ReachEnv",
    "lower_biped": "common.tasks.shape.env:ImitateEnv",
    "biped": "common.tasks.shape.env:ImitateEnv",
    "quadruped": "common.tasks.shape.env:ImitateEnv",
    "fish": "common.tasks.shape.env:ImitateEnv",
    "manta": "common.tasks.shape.env:ImitateEnv",
    "executor": "common.tasks.executor.env:ExecutorEnv",
}


def _env_class(name: str) -> type:
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; registered tasks: {sorted(TASKS)}")
    module, cls = TASKS[name].split(":")
    return getattr(importlib.import_module(module), cls)


def make_env(cfg: TaskConfig, seed: int = 0) -> Env:
    return _env_class(cfg.name)(cfg, seed)


def task_space(cfg: TaskConfig) -> ParamSpace:
    """The task's per-episode parameter space, without building an environment."""
    return _env_class(cfg.name).param_space(cfg)


def task_check(cfg: TaskConfig) -> None:
    """The task's checks of its configuration that need more than range limits (for example
    a data file it reads), without building an environment: ValueError naming what is wrong."""
    check = getattr(_env_class(cfg.name), "check", None)
    if check is not None:
        check(cfg)


def task_clips(cfg: TaskConfig) -> list[tuple[str, str]]:
    """`(clip_id, label)` pairs the task imitates (empty for tasks without motion clips)."""
    return list(_env_class(cfg.name).clips(cfg))
