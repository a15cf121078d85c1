"""Checkpoints: `runs/<name>/ckpt/<iteration>/state.pt`, written atomically, last N kept, and
read back either as raw state (`load`, resuming training) or as a trained policy ready to run
(`load_trained`, `make_policy`: evaluation, live play, distillation).

A checkpoint holds tensors and primitives only, so `torch.load(path, weights_only=True)`
loads it. Atomicity: the file is written and fsynced inside a temporary directory that is
then renamed into place, so a kill mid-write leaves the previous checkpoints untouched and
never a half-written `ckpt/<iteration>/`.
"""

from __future__ import annotations

import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from common.policy import GaussianPolicy
from common.tasks.executor.env import labelled_clips
from learner import checkpoint_check
from learner.config import RunConfig

log = logging.getLogger(__name__)

FORMAT = 1
FILE = "state.pt"


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be used; names the path and why."""


def to_checkpointable(obj: Any) -> Any:
    """numpy arrays -> tensors, recursively, so a sampler state loads with weights_only=True."""
    if isinstance(obj, np.ndarray):
        return torch.from_numpy(np.array(obj))
    if isinstance(obj, dict):
        return {k: to_checkpointable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(to_checkpointable(v) for v in obj)
    return obj


def from_checkpointable(obj: Any) -> Any:
    if isinstance(obj, torch.Tensor):
        return obj.numpy()
    if isinstance(obj, dict):
        return {k: from_checkpointable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(from_checkpointable(v) for v in obj)
    return obj


def save(ckpt_dir: Path, iteration: int, state: dict[str, Any], keep: int) -> Path:
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    final = ckpt_dir / f"{iteration:08d}"
    tmp = ckpt_dir / f".tmp-{iteration:08d}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    with open(tmp / FILE, "wb") as f:
        torch.save({"format": FORMAT, **state}, f)
        f.flush()
        os.fsync(f.fileno())
    replaced = None
    if final.exists():  # the same iteration again (the final save at stop): swap, never a moment without it
        replaced = ckpt_dir / f".old-{iteration:08d}-{os.getpid()}"
        shutil.rmtree(replaced, ignore_errors=True)
        os.replace(final, replaced)
    os.replace(tmp, final)
    dir_fd = os.open(ckpt_dir, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
    if replaced is not None:
        shutil.rmtree(replaced, ignore_errors=True)
    for old in list_checkpoints(ckpt_dir)[:-keep] if keep > 0 else []:
        shutil.rmtree(old, ignore_errors=True)
    return final


def list_checkpoints(ckpt_dir: Path) -> list[Path]:
    """Complete checkpoints, oldest first (temporary directories are ignored)."""
    if not ckpt_dir.is_dir():
        return []
    return sorted(p for p in ckpt_dir.iterdir() if p.is_dir() and p.name.isdigit() and (p / FILE).exists())


def load(path: Path) -> dict[str, Any]:
    """Load one checkpoint directory (or its state.pt) with weights_only=True, and check it
    (`checkpoint_check.problem`): a non-finite tensor or a mistyped field is a `CheckpointError`."""
    file = path / FILE if path.is_dir() else path
    try:
        state = torch.load(file, weights_only=True, map_location="cpu")
    except Exception as exc:  # torch raises many types for truncated or foreign files
        raise CheckpointError(f"checkpoint {file} cannot be read ({type(exc).__name__}: {exc})") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        got = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise CheckpointError(f"checkpoint {file} has format {got!r}; this version reads format {FORMAT}")
    problem = checkpoint_check.problem(state)
    if problem:
        raise CheckpointError(f"checkpoint {file} is refused: {problem}")
    return state


def load_newest_good(ckpt_dir: Path) -> tuple[tuple[Path, dict[str, Any]] | None, list[str]]:
    """The newest checkpoint that loads and passes the checks, and why each newer one was
    refused (one line each, newest first); (None, reasons) when none is good."""
    refused: list[str] = []
    for path in reversed(list_checkpoints(ckpt_dir)):
        try:
            return (path, load(path)), refused
        except CheckpointError as exc:
            refused.append(str(exc))
    return None, refused


def load_latest(ckpt_dir: Path) -> tuple[Path, dict[str, Any]] | None:
    """The newest checkpoint that loads; corrupt or refused ones are logged and skipped."""
    found, refused = load_newest_good(ckpt_dir)
    for why in refused:
        log.error("%s; falling back to the previous checkpoint", why)
    return found


@dataclass(frozen=True)
class Loaded:
    """A checkpoint ready to run: its resolved run config, the raw state and where it came from."""

    cfg: RunConfig
    state: dict[str, Any]
    path: Path

    @property
    def name(self) -> str:
        return self.cfg.name


def resolve(path: str | Path) -> Path:
    """A checkpoint directory (with state.pt), a state.pt file, a run directory (its newest
    `ckpt/<it>/`) or a shipped `learner/pretrained/<name>` -> the state.pt file."""
    p = Path(path)
    if p.is_file():
        return p
    if (p / FILE).is_file():
        return p / FILE
    found = list_checkpoints(p / "ckpt")
    if found:
        return found[-1] / FILE
    raise SystemExit(f"--checkpoint {path}: no state.pt there, nor a run directory with ckpt/<iteration>/state.pt")


def load_trained(path: str | Path) -> Loaded:
    """The checkpoint `resolve(path)` finds, with its saved configuration checked; SystemExit
    with one line naming the file when it is unreadable, not a training checkpoint, or its
    configuration is refused."""
    file = resolve(path)
    try:
        state = load(file)
    except CheckpointError as exc:
        raise SystemExit(str(exc)) from None
    if "config" not in state or "policy" not in state:
        raise SystemExit(f"{file} holds no 'config'/'policy': not a morphmimic training checkpoint")
    try:
        cfg = RunConfig.from_json(str(state["config"]))
        if cfg.task.name == "executor":  # its named clips must play on the humanoid
            labelled_clips(cfg.task)
    except ValueError as exc:
        raise SystemExit(f"{file}: its saved configuration is refused: {exc}") from None
    return Loaded(cfg, state, file)


def make_policy(loaded: Loaded, obs_dim: int, act_dim: int) -> GaussianPolicy:
    """The checkpoint's policy for an env of these sizes, in eval mode; SystemExit naming the
    file when its weights do not fit."""
    policy = GaussianPolicy(obs_dim, act_dim, loaded.cfg.policy)
    try:
        policy.load_state_dict(loaded.state["policy"])
    except (RuntimeError, TypeError, AttributeError) as exc:  # wrong shapes or keys; not a state dict at all
        raise SystemExit(f"{loaded.path}: the policy does not fit task {loaded.cfg.task.name!r} as this code builds it "
                         f"(obs {obs_dim}, act {act_dim}): {exc}") from None
    policy.eval()
    return policy
