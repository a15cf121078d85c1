"""Where a run stands before `morphmimic train` starts anything: new (no checkpoint yet), or
finished (its newest checkpoint already has the step budget or iteration limit asked for). A
finished run is said in one line, with where its checkpoint is and how to extend it, and Ray is
never started for it: re-running a command that already did its work costs seconds, not a
cluster start-up, a resume and a drain that trains nothing.
"""

from __future__ import annotations

from pathlib import Path

from learner import checkpoint
from learner.config import RunConfig


def is_new(cfg: RunConfig) -> bool:
    """True when this command starts a run from nothing: no checkpoint in its run directory and
    none named by --resume."""
    if cfg.resume not in ("auto", "never"):
        return False
    return not checkpoint.list_checkpoints(Path(cfg.runs_dir) / cfg.name / "ckpt")


def finished_line(cfg: RunConfig) -> str | None:
    """The one line saying the run is finished, or None when there is training left to do (or
    the newest checkpoint does not load: training then reports it as it always does). Only with
    --resume auto, the mode that continues the run's own checkpoints."""
    if cfg.resume != "auto":
        return None
    found = checkpoint.list_checkpoints(Path(cfg.runs_dir) / cfg.name / "ckpt")
    if not found:
        return None
    try:
        state = checkpoint.load(found[-1])
    except checkpoint.CheckpointError:
        return None
    steps, iteration = int(state.get("env_steps", 0)), int(state.get("iteration", 0))
    if steps >= cfg.total_env_steps:
        why = f"{steps:,d} env steps of a budget of {cfg.total_env_steps:,d}"
        extend = f"give a larger --total-env-steps (say {2 * cfg.total_env_steps})"
    elif cfg.max_iterations and iteration >= cfg.max_iterations:
        why = f"iteration {iteration} of --max-iterations {cfg.max_iterations}"
        extend = f"give a larger --max-iterations (say {2 * cfg.max_iterations}; 0: no limit)"
    else:
        return None
    return (f"[morphmimic] run {Path(cfg.runs_dir) / cfg.name} is finished ({why}); checkpoint {found[-1]}. "
            f"To train it on, run the same command and {extend}; to start afresh, give another --name.")
