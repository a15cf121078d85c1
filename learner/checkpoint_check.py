"""What a checkpoint must hold before anything runs or resumes from it: every tensor finite,
every field of the learner's state of its type and range.

A checkpoint with NaN weights used to start (`--resume`): every actor refused the weights and
the learner waited forever; `evaluate` raised a traceback. `problem(state)` finds the first
such defect and says it in one line, which `checkpoint.load` turns into a `CheckpointError`
(one line and exit 2 for `--resume`, `evaluate`, `play` and `studio`; skipped by `--resume auto`).
Only fields that are present are checked, so partial states (tests, tools) still load.
"""

from __future__ import annotations

import math
from typing import Any

import torch

COUNTS = ("iteration", "env_steps", "policy_version", "episodes")
"""Whole numbers >= 0 at the top of a learner's state."""
MAX_DEPTH = 16
"""Nesting the tensor walk follows; a state nests 4 deep (sampler -> arrays -> name -> tensor)."""
_UNEXPLAINED = ("unrolls_received", "unrolls_trained", "stale_unrolls", "unused_at_stop", "unused_at_resume")
"""Transport counters: received, and what explains a received unroll (`pending_unrolls` is the rest)."""


def _whole(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _first_nonfinite(obj: Any, where: str, depth: int = 0) -> str | None:
    """The path of the first floating tensor holding NaN or Inf, or of a nesting too deep."""
    if depth > MAX_DEPTH:
        return f"{where} (nested deeper than {MAX_DEPTH})"
    if isinstance(obj, torch.Tensor):
        if (obj.is_floating_point() or obj.is_complex()) and not bool(torch.isfinite(obj).all()):
            return where
        return None
    if isinstance(obj, dict):
        items = obj.items()
    elif isinstance(obj, (list, tuple)):
        items = enumerate(obj)
    else:
        return None
    for key, value in items:
        found = _first_nonfinite(value, f"{where}[{key!r}]", depth + 1)
        if found:
            return found
    return None


def _counter_map(value: Any, name: str) -> str | None:
    if not isinstance(value, dict):
        return f"{name} is a {type(value).__name__}; expected a dict of name -> count"
    for key, count in value.items():
        if not isinstance(key, str) or not _number(count) or not math.isfinite(count) or count < 0:
            return f"{name}[{key!r}] = {count!r}; expected a finite count >= 0 under a string name"
    return None


def _pending_problem(transport: Any) -> str | None:
    """`transport.pending_unrolls` (unrolls received but not yet in a batch at the save): a whole
    number no larger than the received unrolls its counters leave unexplained."""
    if not isinstance(transport, dict) or "pending_unrolls" not in transport:
        return None
    pending = transport["pending_unrolls"]
    if not _whole(pending):
        return f"transport['pending_unrolls'] = {pending!r}; expected a whole number >= 0"
    c = transport.get("counters")
    if isinstance(c, dict) and all(_whole(c.get(k, 0)) for k in _UNEXPLAINED):
        room = c.get("unrolls_received", 0) - sum(c.get(k, 0) for k in _UNEXPLAINED[1:])
        if pending > room:
            return (f"transport['pending_unrolls'] = {pending}; at most {max(room, 0)} (unrolls received and "
                    f"not yet trained, stale or unused)")
    return None


def problem(state: dict[str, Any]) -> str | None:
    """One line naming the first defect of a loaded checkpoint `state`, or None if it is sound."""
    for key in COUNTS:
        if key in state and not _whole(state[key]):
            return f"{key} = {state[key]!r} ({type(state[key]).__name__}); expected a whole number >= 0"
    if "config" in state and not isinstance(state["config"], str):
        return f"config is a {type(state['config']).__name__}; expected the run configuration as JSON text"
    if "lr" in state and not (_number(state["lr"]) and math.isfinite(state["lr"]) and state["lr"] > 0):
        return f"lr = {state['lr']!r}; expected a finite learning rate > 0"
    if "train_seconds" in state:  # NOTE: NaN is "unknown" (a run begun before it was counted)
        t = state["train_seconds"]
        if not _number(t) or math.isinf(t) or t < 0:
            return f"train_seconds = {t!r}; expected seconds >= 0 (or NaN: unknown)"
    for key in ("policy", "value", "optimizer"):
        if key in state and not isinstance(state[key], dict):
            return f"{key} is a {type(state[key]).__name__}; expected a state dict"
    if "counters" in state:
        found = _counter_map(state["counters"], "counters")
        if found:
            return found
    for key in ("recent_returns", "recent_lengths"):
        values = state.get(key, [])
        if not isinstance(values, list) or not all(_number(v) and math.isfinite(v) for v in values):
            return f"{key} must be a list of finite numbers"
    found = _pending_problem(state.get("transport"))
    if found:
        return found
    for family in ("transport", "faults"):
        part = state.get(family)
        if part is None:
            continue
        if not isinstance(part, dict):
            return f"{family} is a {type(part).__name__}; expected a dict"
        for key, value in part.items():
            if key == "last_seq":  # sequence numbers, -1 included: checked by the transport's own load
                continue
            if isinstance(value, dict):
                found = _counter_map(value, f"{family}[{key!r}]")
            elif not (_number(value) and math.isfinite(value) and value >= 0):
                found = f"{family}[{key!r}] = {value!r}; expected a finite count >= 0"
            else:
                found = None
            if found:
                return found
    where = _first_nonfinite(state, "state")
    if where:
        return f"{where} holds NaN or Inf (a diverged run?); resume from an earlier checkpoint"
    return None
