"""Which evaluation a checkpoint gets (learner/evaluation/registry.py): by its task's family in
common/tasks/registry.py, and a one-line refusal for a task without one."""

from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path

import pytest

from common.tasks.registry import TASKS, command_refusal
from learner import checkpoint
from learner.evaluation import registry
from learner.presets import PRESETS


def test_every_task_listing_an_evaluation_command_has_an_evaluator() -> None:
    for name, entry in TASKS.items():
        for command in ("evaluate", "ablation", "learning-curve"):
            if command in entry.commands:
                assert registry.family_of(name, command) in registry.FAMILIES, name
        for command in ("evaluate", "ablation"):
            if command in entry.commands:  # an evaluator names a function for every command its tasks list
                module, func = getattr(registry.evaluator_for(name, command), command).split(":")
                assert callable(getattr(importlib.import_module(module), func)), (name, command)


@pytest.mark.parametrize("command, module, flag", [("ablation", "learner.evaluation.ablation", "--checkpoints"),
                                                   ("robustness", "learner.evaluation.executor.robustness", "--checkpoint")])
def test_a_reach_checkpoint_is_refused_in_one_line_naming_what_it_works_with(command, module, flag, tmp_path: Path,
                                                                             capsys) -> None:
    from learner.learner import Learner

    cfg = dataclasses.replace(PRESETS["reach-tiny"][1], name="reach")
    checkpoint.save(tmp_path / "reach" / "ckpt", 0, Learner(cfg).state_dict(), keep=1)
    with pytest.raises(SystemExit) as exc:
        importlib.import_module(module).main([flag, str(tmp_path / "reach"), "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"morphmimic {command}: task 'reach' has no {command} (it takes lower_biped, biped, quadruped, fish, "
                   "manta, executor); reach checkpoints work with: train, evaluate, learning-curve, play, studio"), err
    assert not (tmp_path / "o").exists()


def test_a_command_no_task_offers_is_refused_saying_so() -> None:
    assert command_refusal("reach", "break-probe") == ("task 'reach' has no break-probe (it takes executor); reach "
                                                       "checkpoints work with: train, evaluate, learning-curve, play, studio")
    assert command_refusal("fish", "play") is None
    assert "it takes no task's checkpoints" in command_refusal("fish", "no-such-command")


def test_an_ablation_of_two_families_is_refused_in_one_line(tmp_path: Path, capsys) -> None:
    from learner.learner import Learner
    from tests.learner.evaluation.executor_checkpoints import tiny_executor

    for preset, name in (("reach-tiny", "reach"), ("lower_biped-tiny", "walker")):
        cfg = dataclasses.replace(PRESETS[preset][1], name=name)
        checkpoint.save(tmp_path / name / "ckpt", 0, Learner(cfg).state_dict(), keep=1)
    executor = tiny_executor(tmp_path)
    ablation = importlib.import_module("learner.evaluation.ablation")
    for other, says in ((executor, f"--checkpoints {executor}: task 'executor' (family 'executor'), but "
                                   f"{tmp_path / 'walker'} is 'lower_biped' ('shape'): one ablation compares checkpoints "
                                   "of one family"),
                        (tmp_path / "reach", "task 'reach' has no ablation")):
        with pytest.raises(SystemExit) as exc:
            ablation.main(["--checkpoints", str(tmp_path / "walker"), str(other), "--out", str(tmp_path / "o")])
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "o").exists()
