"""Which evaluation a checkpoint gets (learner/evaluation/registry.py): by its task's family in
common/tasks/registry.py, and a one-line refusal for a task without one."""

from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path

import pytest

from common.tasks.registry import TASKS
from learner import checkpoint
from learner.evaluation import registry
from learner.presets import PRESETS


def test_every_task_listing_an_evaluation_command_has_an_evaluator() -> None:
    for name, entry in TASKS.items():
        for command in ("evaluate", "ablation", "learning-curve"):
            if command in entry.commands:
                assert registry.family_of(name, command) in registry.FAMILIES, name
        for command in ("evaluate", "ablation"):
            if command in entry.commands:
                module, func = getattr(registry.evaluator_for(name, command), command).split(":")
                assert callable(getattr(importlib.import_module(module), func)), (name, command)


@pytest.mark.parametrize("command, module, flag", [("evaluate", "evaluate", "--checkpoint"),
                                                   ("ablation", "ablation", "--checkpoints"),
                                                   ("learning-curve", "learning_curve", "--ckpt-dir")])
def test_a_reach_checkpoint_is_refused_in_one_line_naming_what_it_works_with(command, module, flag, tmp_path: Path,
                                                                             capsys) -> None:
    from learner.learner import Learner

    cfg = dataclasses.replace(PRESETS["reach-tiny"][1], name="reach")
    checkpoint.save(tmp_path / "reach" / "ckpt", 0, Learner(cfg).state_dict(), keep=1)
    target = tmp_path / "reach" / ("ckpt" if flag == "--ckpt-dir" else "")
    with pytest.raises(SystemExit) as exc:
        importlib.import_module(f"learner.evaluation.{module}").main([flag, str(target), "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err == f"morphmimic {command}: task 'reach' has no {command}; its checkpoints work with: train", err
