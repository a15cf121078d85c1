"""Which evaluation a checkpoint gets: each task family with an evaluation (`common.tasks.registry`:
a task's `family`) exposes an `Evaluator` from its package (`learner/evaluation/<family>/`), and
`morphmimic evaluate`, `ablation` and `learning-curve` look the checkpoint's task up here instead
of guessing from its options. A task whose entry does not list the command is refused in one
line naming the tasks the command takes and the commands its checkpoints do work with
(`common.tasks.registry.command_refusal`, exit 2)."""

from __future__ import annotations

import importlib
import sys
from dataclasses import dataclass
from typing import Callable

from common.tasks.registry import command_refusal, task_entry

FAMILIES: dict[str, str] = {
    "reach": "learner.evaluation.reach",
    "shape": "learner.evaluation.shape",
    "executor": "learner.evaluation.executor",
}
"""Task family -> the package whose `EVALUATOR` evaluates its checkpoints."""


@dataclass(frozen=True)
class Evaluator:
    """A family's evaluation commands, each `module:function` taking the command's arguments and
    returning its exit code; imported only when run."""

    evaluate: str
    ablation: str = ""
    """Empty: the family has no ablation table (its tasks' entries do not list `ablation`)."""

    def run(self, command: str, argv: list[str]) -> int:
        module, func = getattr(self, command).split(":")
        entry: Callable[[list[str]], int] = getattr(importlib.import_module(module), func)
        return int(entry(argv) or 0)


def family_of(task: str, command: str) -> str:
    """`task`'s family, whose evaluation `morphmimic <command>` runs; SystemExit(2) after one line
    on stderr when the task's checkpoints are not for that command."""
    entry = task_entry(task)
    refusal = command_refusal(task, command)
    if refusal is None and entry.family not in FAMILIES:
        refusal = f"task {task!r} (family {entry.family!r}) has no evaluation; add one to learner/evaluation/registry.py"
    if refusal is not None:
        print(f"morphmimic {command}: {refusal}", file=sys.stderr)
        raise SystemExit(2)
    return entry.family


def evaluator_for(task: str, command: str) -> Evaluator:
    """The evaluator of `task`'s family for `morphmimic <command>` (refused as in `family_of`)."""
    return importlib.import_module(FAMILIES[family_of(task, command)]).EVALUATOR


def first_value(argv: list[str], flag: str) -> str | None:
    """The first value given to `flag` (`--flag v` or `--flag=v`), None without one."""
    for i, arg in enumerate(argv):
        if arg == flag and i + 1 < len(argv) and not argv[i + 1].startswith("--"):
            return argv[i + 1]
        if arg.startswith(flag + "="):
            return arg.split("=", 1)[1]
    return None


def later_values(argv: list[str], flag: str) -> list[str]:
    """The values after the first one given to `flag` (`--checkpoints A B C` -> [B, C]), up to the
    next option."""
    for i, arg in enumerate(argv):
        if arg == flag:
            rest = []
            for value in argv[i + 2:]:
                if value.startswith("--"):
                    break
                rest.append(value)
            return rest
    return []


DEFAULT_FAMILY = "shape"
"""Whose command parses the arguments when the checkpoint cannot be read: its parser names a bad
option first, then the checkpoint (the shape evaluation's; any family's would do)."""


def dispatch(command: str, argv: list[str], checkpoint_flag: str) -> int:
    """Run `morphmimic <command>` with the evaluator of the task of the (first) checkpoint given
    by `checkpoint_flag`. Every further checkpoint (`ablation --checkpoints A B ...`) must be of a
    task the command takes, of the same family: refused in one line otherwise (exit 2)."""
    from learner import checkpoint  # lazy: heavy (torch); the family packages import this module

    path = first_value(argv, checkpoint_flag)
    try:
        task = checkpoint.load_trained(path).cfg.task.name if path is not None else None
    except SystemExit:
        task = None
    if task is None:
        return importlib.import_module(FAMILIES[DEFAULT_FAMILY]).EVALUATOR.run(command, argv)
    evaluator, family = evaluator_for(task, command), task_entry(task).family
    for other in later_values(argv, checkpoint_flag):
        try:
            other_task = checkpoint.load_trained(other).cfg.task.name
        except SystemExit:
            continue  # the family's own command names an unreadable checkpoint
        if family_of(other_task, command) != family:
            print(f"morphmimic {command}: {checkpoint_flag} {other}: task {other_task!r} (family "
                  f"{task_entry(other_task).family!r}), but {path} is {task!r} ({family!r}): one {command} compares "
                  "checkpoints of one family", file=sys.stderr)
            raise SystemExit(2)
    return evaluator.run(command, argv)
