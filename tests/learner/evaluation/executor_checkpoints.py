"""Untrained executor checkpoints for the evaluation tests (a Learner's initial state, no training)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from learner import checkpoint
from learner.presets import PRESETS


def tiny_executor(tmp: Path, name: str = "xtiny", **executor_changes) -> Path:
    """An `executor-tiny` checkpoint (64 x 64 policy) with some ExecutorConfig fields changed;
    returns its run directory."""
    from learner.learner import Learner

    cfg = PRESETS["executor-tiny"][1]
    task = dataclasses.replace(cfg.task, executor=dataclasses.replace(cfg.task.executor, **executor_changes))
    cfg = dataclasses.replace(cfg, name=name, task=task)
    checkpoint.save(tmp / name / "ckpt", 0, Learner(cfg).state_dict(), keep=1)
    return tmp / name
