"""Bad checkpoints are refused in one line (issue 54, item 5): NaN weights or statistics and
mistyped fields are refused by `train --resume`, `evaluate`, `play` and `studio` with exit 2 and
no traceback, and `--resume auto` falls back to the newest good checkpoint and says which."""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from learner import checkpoint, checkpoint_check
from learner.presets import PRESETS
from learner.train import train

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A real tiny serial run with checkpoints at iterations 1 and 2; the second then gets a NaN
    weight, as a diverged run would leave it."""
    root = tmp_path_factory.mktemp("runs")
    cfg = dataclasses.replace(PRESETS["reach-tiny"][1], runs_dir=str(root), quiet=True, mode="serial",
                              max_iterations=2, checkpoint_every=1, total_env_steps=10**6)
    assert train(cfg) == 0
    run = root / "reach-tiny"
    assert [p.name for p in checkpoint.list_checkpoints(run / "ckpt")] == ["00000001", "00000002"]
    file = run / "ckpt" / "00000002" / checkpoint.FILE
    state = torch.load(file, weights_only=True)
    name = next(k for k in state["policy"] if k.endswith("weight"))
    state["policy"][name][0, 0] = float("nan")
    torch.save(state, file)
    return run


def _cli(*args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    return subprocess.run([sys.executable, "-m", "learner.cli", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout, check=False)


def _refused_in_one_line(proc: subprocess.CompletedProcess, *words: str) -> None:
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and " INFO " not in ln]
    assert len(lines) == 1, proc.stderr
    for word in words:
        assert word in lines[0], lines[0]


@pytest.mark.parametrize("command", [
    ["train", "--preset", "reach-tiny", "--mode", "serial", "--resume"],
    ["evaluate", "--shapes", "2", "--episode-s", "1", "--checkpoint"],
    ["play", "--seconds", "1", "--checkpoint"],
    ["studio", "--seconds", "1", "--port", "0", "--checkpoint"],
])
def test_a_nan_checkpoint_is_refused_by_every_command_in_one_line(run_dir, tmp_path, command):
    extra = ["--runs-dir", str(tmp_path)] if command[0] == "train" else []
    proc = _cli(*command, str(run_dir / "ckpt" / "00000002"), *extra)
    _refused_in_one_line(proc, "00000002", "NaN")
    if command[0] == "train":
        assert not (tmp_path / "reach-tiny").exists()  # refused before any run folder was made


def test_resume_auto_falls_back_to_the_newest_good_checkpoint_and_says_which(run_dir, tmp_path):
    run_dir = Path(shutil.copytree(run_dir, tmp_path / "reach-tiny"))  # the other tests keep the NaN one
    proc = _cli("train", "--preset", "reach-tiny", "--mode", "serial", "--runs-dir", str(run_dir.parent),
                "--max-iterations", "3", "--total-env-steps", "1000000", "--checkpoint-every", "1")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "falling back to " + str(run_dir / "ckpt" / "00000001") in proc.stdout
    assert "00000002" in proc.stdout and "NaN" in proc.stdout  # and why the newer one was refused
    assert "resumed " + str(run_dir / "ckpt" / "00000001") + " at iteration 1" in proc.stdout
    state = checkpoint.load(run_dir / "ckpt" / "00000003")  # it trained on and wrote sound ones
    assert state["iteration"] == 3


def test_resume_auto_with_no_good_checkpoint_exits_2(tmp_path):
    ckpt = tmp_path / "reach-tiny" / "ckpt"
    checkpoint.save(ckpt, 1, {"iteration": 1, "weights": torch.full((2,), float("inf"))}, keep=3)
    proc = _cli("train", "--preset", "reach-tiny", "--mode", "serial", "--runs-dir", str(tmp_path))
    _refused_in_one_line(proc, "no checkpoint", "usable", "Inf")


@pytest.mark.parametrize("field, value, words", [
    ("iteration", "2", ["iteration", "'2'", "whole number"]),
    ("env_steps", -5, ["env_steps", "-5"]),
    ("lr", float("nan"), ["lr", "nan"]),
    ("config", 7, ["config", "JSON"]),
    ("counters", {"divergences": -1}, ["counters", "divergences"]),
    ("recent_returns", [1.0, float("inf")], ["recent_returns", "finite"]),
    ("transport", {"pending_unrolls": 1.5}, ["pending_unrolls", "1.5", "whole number"]),
    ("transport", {"pending_unrolls": 9, "counters": {"unrolls_received": 10, "unrolls_trained": 4}},
     ["pending_unrolls", "at most 6"]),
])
def test_mistyped_fields_are_named(field, value, words):
    problem = checkpoint_check.problem({"iteration": 2, "env_steps": 10, "lr": 1e-3, "config": "{}", field: value})
    assert problem is not None
    for word in words:
        assert word in problem, problem


def test_a_sound_state_and_an_unknown_training_time_pass():
    state = {"iteration": 2, "env_steps": 10, "lr": 1e-3, "train_seconds": float("nan"),
             "policy": {"w": torch.zeros(2, 2)}, "transport": {"last_seq": {"0": -1}, "counters": {"x": 3, "unrolls_received": 3}, "pending_unrolls": 3}}
    assert checkpoint_check.problem(state) is None
    state["policy"]["normalizer.var"] = torch.tensor([1.0, float("nan")], dtype=torch.float64)
    assert "normalizer.var" in checkpoint_check.problem(state)
