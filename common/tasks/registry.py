"""One registry of tasks: each task's environment class, family and the commands that take its
checkpoints (`TASKS`), and `make_env(cfg, seed)`, `task_space(cfg)`, `task_bounds(cfg)` by task name.

`TaskEntry.commands` is the one place that says which `morphmimic` commands work on a task's
checkpoints: every command that takes a checkpoint asks `command_refusal` first, so a task a
command does not serve is refused in one line naming the tasks it does serve
(docs/commands.md has the table)."""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Sequence

from common.params import ParamSpace
from common.tasks.base import Env, TaskConfig
from common.tasks.batch import BatchEnv, LoopBatch
from common.tasks.content_bounds import ContentBounds

REACH_COMMANDS = ("train", "evaluate", "learning-curve", "play", "studio")
"""No ablation (nothing to ablate yet) and no robustness (UniCon's table perturbs a character's
balance; the arm floats without gravity and has no body to push or throw at)."""
SHAPE_COMMANDS = ("train", "curriculum", "evaluate", "ablation", "learning-curve", "robustness", "play", "studio")
EXECUTOR_COMMANDS = ("train", "distill", "evaluate", "ablation", "learning-curve", "robustness", "velocity-probe",
                     "break-probe", "play", "studio")


@dataclass(frozen=True)
class TaskEntry:
    """One registered task: where its environment class is, the family of tasks it belongs to
    (tasks of one family share an evaluation: "reach", "shape", "executor") and the `morphmimic`
    commands that take its checkpoints."""

    env: str
    """The environment class as `module:Class`."""
    family: str
    commands: tuple[str, ...]
    batch: str = ""
    """The task's batched environment class as `module:Class` (`common.tasks.batch.BatchEnv`,
    built as `Class(cfg, seeds)`); empty: a `LoopBatch` of single environments."""
    durations: str = ""
    """`module:function` giving {clip id: length in s} of the task's clips from its config
    (`task_clip_durations`); empty: the task takes no start times from the sampler."""


TASKS: dict[str, TaskEntry] = {
    "reach": TaskEntry("common.tasks.reach:ReachEnv", "reach", REACH_COMMANDS),
    **{name: TaskEntry("common.tasks.shape.env:ImitateEnv", "shape", SHAPE_COMMANDS,
                       batch="common.tasks.shape.batch:ShapeBatch")
       for name in ("lower_biped", "biped", "quadruped", "fish", "manta")},
    "executor": TaskEntry("common.tasks.executor.env:ExecutorEnv", "executor", EXECUTOR_COMMANDS,
                          batch="common.tasks.executor.batch:ExecutorBatch",
                          durations="common.tasks.executor.clip_durations:executor_clip_durations"),
}


def task_entry(name: str) -> TaskEntry:
    """The registered task `name`; ValueError naming it and the registered tasks otherwise."""
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; registered tasks: {sorted(TASKS)}")
    return TASKS[name]


def tasks_offering(command: str) -> list[str]:
    """The registered tasks whose checkpoints `morphmimic <command>` takes, in registry order."""
    return [name for name, entry in TASKS.items() if command in entry.commands]


def command_refusal(task: str, command: str) -> str | None:
    """None when `morphmimic <command>` takes checkpoints of `task`; otherwise the one-line refusal:
    the tasks it does take and the commands that take this task's checkpoints."""
    entry = task_entry(task)
    if command in entry.commands:
        return None
    offering = tasks_offering(command)
    takes = f"it takes {', '.join(offering)}" if offering else "it takes no task's checkpoints"
    return f"task {task!r} has no {command} ({takes}); {task} checkpoints work with: {', '.join(entry.commands)}"


def _env_class(name: str) -> type:
    module, cls = task_entry(name).env.split(":")
    return getattr(importlib.import_module(module), cls)


def make_env(cfg: TaskConfig, seed: int = 0) -> Env:
    return _env_class(cfg.name)(cfg, seed)


def make_batch_env(cfg: TaskConfig, seeds: Sequence[int]) -> BatchEnv:
    """The task's N = len(seeds) environments as one batch: its own batched class if it
    registers one (`TaskEntry.batch`), else a `LoopBatch`; environment i behaves as
    `make_env(cfg, seeds[i])`."""
    path = task_entry(cfg.name).batch
    if not path:
        return LoopBatch([make_env(cfg, seed) for seed in seeds])
    module, cls = path.split(":")
    return getattr(importlib.import_module(module), cls)(cfg, list(seeds))


def task_space(cfg: TaskConfig) -> ParamSpace:
    """The task's per-episode parameter space, without building an environment."""
    return _env_class(cfg.name).param_space(cfg)


def task_bounds(cfg: TaskConfig) -> ContentBounds:
    """What one step of the task can hold (reward range, observation magnitude, horizon), as the
    task declares it beside its reward; the learner drops an unroll outside it."""
    return _env_class(cfg.name).content_bounds(cfg)


def task_check(cfg: TaskConfig) -> None:
    """The task's checks of its configuration that need more than range limits (for example
    a data file it reads), without building an environment: ValueError naming what is wrong."""
    check = getattr(_env_class(cfg.name), "check", None)
    if check is not None:
        check(cfg)


def task_clips(cfg: TaskConfig) -> list[tuple[str, str]]:
    """`(clip_id, label)` pairs the task imitates (empty for tasks without motion clips)."""
    return list(_env_class(cfg.name).clips(cfg))


def task_clip_durations(cfg: TaskConfig) -> dict[str, float]:
    """{clip id: length in s} of the clips the task draws, for the sampler's start times
    (`--sampler.time-bin-s`); empty for a task whose episodes take no start time from a draw."""
    path = task_entry(cfg.name).durations
    if not path:
        return {}
    module, fn = path.split(":")
    return dict(getattr(importlib.import_module(module), fn)(cfg))
