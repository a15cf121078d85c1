"""Executor checkpoints for the evaluation tests: untrained ones (a Learner's initial state, no
training) and a tiny shape-conditioned one really trained by the training command in serial mode."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from learner import checkpoint
from learner.presets import PRESETS

SHAPE_CLIPS = ("humanoid3d_walk",)
"""The clips the tiny shape executor trains on (one: the run is a few seconds)."""


def tiny_executor(tmp: Path, name: str = "xtiny", **executor_changes) -> Path:
    """An `executor-tiny` checkpoint (64 x 64 policy) with some ExecutorConfig fields changed;
    returns its run directory."""
    from learner.learner import Learner

    cfg = PRESETS["executor-tiny"][1]
    task = dataclasses.replace(cfg.task, executor=dataclasses.replace(cfg.task.executor, **executor_changes))
    cfg = dataclasses.replace(cfg, name=name, task=task)
    checkpoint.save(tmp / name / "ckpt", 0, Learner(cfg).state_dict(), keep=1)
    return tmp / name


def tiny_shape_executor(tmp: Path, name: str = "xshape", iterations: int = 2) -> Path:
    """The `executor-shape` preset (`--task.body.vary-shape` over height x thickness) with a
    64 x 64 policy on `SHAPE_CLIPS`, really trained for `iterations` PPO iterations of 256 steps
    by `learner.train.train` in serial mode (one process, no Ray; the learner's sockets on
    127.0.0.1); returns its run directory."""
    from learner.train import train

    base = PRESETS["executor-shape"][1]
    assert base.task.body.vary_shape
    ex = dataclasses.replace(base.task.executor, clips=SHAPE_CLIPS)
    cfg = dataclasses.replace(
        base, name=name, runs_dir=str(tmp), quiet=True, mode="serial", max_iterations=iterations,
        total_env_steps=10**6, steps_per_iteration=256, checkpoint_every=1,
        task=dataclasses.replace(base.task, executor=ex),
        policy=dataclasses.replace(base.policy, hidden=(64, 64)),
        ppo=dataclasses.replace(base.ppo, minibatch=128, epochs=1),
        actors=dataclasses.replace(base.actors, num_actors=1, envs_per_actor=4, unroll_length=32),
    )
    assert train(cfg) == 0
    return tmp / name
