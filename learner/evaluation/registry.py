"""Which evaluation a checkpoint gets: each task family with an evaluation (`common.tasks.registry`:
a task's `family`) exposes an `Evaluator` from its package (`learner/evaluation/<family>/`), and
`morphmimic evaluate`, `ablation` and `learning-curve` look the checkpoint's task up here instead
of guessing from its options. A task whose family has none, or whose entry does not list the
command, is refused in one line naming the commands its checkpoints do work with (exit 2)."""

from __future__ import annotations

import importlib
import sys
from dataclasses import dataclass
from typing import Callable

from common.tasks.registry import task_entry

FAMILIES: dict[str, str] = {
    "shape": "learner.evaluation.shape",
    "executor": "learner.evaluation.executor",
}
"""Task family -> the package whose `EVALUATOR` evaluates its checkpoints."""


@dataclass(frozen=True)
class Evaluator:
    """A family's evaluation commands, each `module:function` taking the command's arguments and
    returning its exit code; imported only when run."""

    evaluate: str
    ablation: str

    def run(self, command: str, argv: list[str]) -> int:
        module, func = getattr(self, command).split(":")
        entry: Callable[[list[str]], int] = getattr(importlib.import_module(module), func)
        return int(entry(argv) or 0)


def family_of(task: str, command: str) -> str:
    """`task`'s family, whose evaluation `morphmimic <command>` runs; SystemExit(2) after one line
    on stderr when the task's checkpoints are not for that command."""
    entry = task_entry(task)
    if command not in entry.commands or entry.family not in FAMILIES:
        print(f"morphmimic {command}: task {task!r} has no {command}; its checkpoints work with: "
              f"{', '.join(entry.commands)}", file=sys.stderr)
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


DEFAULT_FAMILY = "shape"
"""Whose command parses the arguments when the checkpoint cannot be read: its parser names a bad
option first, then the checkpoint (the shape evaluation's; any family's would do)."""


def dispatch(command: str, argv: list[str], checkpoint_flag: str) -> int:
    """Run `morphmimic <command>` with the evaluator of the task of the (first) checkpoint given
    by `checkpoint_flag`."""
    from learner import checkpoint  # lazy: heavy (torch); the family packages import this module

    path = first_value(argv, checkpoint_flag)
    try:
        task = checkpoint.load_trained(path).cfg.task.name if path is not None else None
    except SystemExit:
        task = None
    if task is None:
        return importlib.import_module(FAMILIES[DEFAULT_FAMILY]).EVALUATOR.run(command, argv)
    return evaluator_for(task, command).run(command, argv)
