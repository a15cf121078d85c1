"""argparse `type=` converters of the evaluation commands (evaluate, ablation, robustness,
learning_curve, morph_demo) and the benchmarks: each turns bad input into a usage error that names the value and what is allowed,
before any checkpoint is loaded or any episode run."""

from __future__ import annotations

import argparse
import json
import math

from learner.evaluation.harness import check_box_scale


def _number(text: str, kind: type, allowed: str) -> float:
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}; "
                                         f"it must be {allowed}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} must be {allowed}")
    return value


def _within(text: str, kind: type, ok, allowed: str):
    """`text` as a `kind` for which `ok(value)` holds; a usage error saying it must be `allowed` otherwise."""
    value = _number(text, kind, allowed)
    if not ok(value):
        raise argparse.ArgumentTypeError(f"{text!r} must be {allowed}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1 (shape counts, worker counts, strides)."""
    return _within(text, int, lambda v: v >= 1, "an integer >= 1")


def positive_ints(text: str) -> list[int]:
    """Comma-separated integers >= 1 (`--widths 128,256`, `--actors 1,2,4,8`)."""
    parts = [x.strip() for x in text.split(",") if x.strip()]
    if not parts:
        raise argparse.ArgumentTypeError(f"{text!r}: give comma-separated integers >= 1, e.g. 1,2,4,8")
    return [positive_int(x) for x in parts]


def seed(text: str) -> int:
    """A random seed: an integer >= 0 (numpy's generators refuse negative seeds) and below 2^32
    (torch's manual_seed overflows past 2^64)."""
    return _within(text, int, lambda v: 0 <= v < 2**32, "an integer >= 0 and below 2^32")


def unix_time(text: str) -> float:
    """A Unix time in seconds: a finite number >= 0 (0: not given)."""
    return _within(text, float, lambda v: v >= 0, "a finite number of seconds >= 0 (a Unix time)")


def percent(text: str) -> float:
    """A percentage in [0, 100] (a fall-down target)."""
    return _within(text, float, lambda v: 0.0 <= v <= 100.0, "a number in [0, 100]")


def positive_float(text: str) -> float:
    """A finite number > 0 (episode lengths in seconds)."""
    return _within(text, float, lambda v: v > 0, "a finite number > 0")


def clearance(text: str) -> float:
    """A body clearance in metres, in [0, 0.1] (`--task.imitate.retarget.body-clearance-m`'s range)."""
    return _within(text, float, lambda v: 0.0 <= v <= 0.1, "a number of metres in [0, 0.1]")


def port(text: str) -> int:
    """A TCP/UDP port: an integer in [0, 65535] (0: the system picks a free one)."""
    return _within(text, int, lambda v: 0 <= v <= 65535, "an integer in [0, 65535]")


def finite_float(text: str) -> float:
    """Any finite number (the morph strength: negative mirrors the schedule, 0 keeps the base shape)."""
    return _number(text, float, "a finite number")


def box_scale(text: str) -> float:
    """A float in (0, 1]: the shape box shrunk toward the base shape (1: the whole box)."""
    value = _number(text, float, "in (0, 1] (1: the whole box)")
    try:
        return check_box_scale(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None


def morph_schedule(text: str) -> list[tuple[float, dict[str, float]]]:
    """JSON keyframes `[[time_s, {parameter: value}], ...]` with times >= 0 and strictly
    increasing (the morph interpolates between them) and finite values. Parameter names are
    checked against the checkpoint's shape space when the schedule is used."""
    allowed = 'JSON keyframes [[time_s, {"parameter": value}], ...] with times >= 0 strictly increasing'
    try:
        raw = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"{text!r} is not JSON ({exc.msg}); it must be {allowed}") from None
    if not isinstance(raw, list) or not raw:
        raise argparse.ArgumentTypeError(f"{text!r} must be a non-empty list of {allowed}")
    keys: list[tuple[float, dict[str, float]]] = []
    for k in raw:
        ok = isinstance(k, list) and len(k) == 2 and isinstance(k[1], dict)
        t = k[0] if ok else None
        if not ok or isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
            raise argparse.ArgumentTypeError(f"keyframe {json.dumps(k)} in {text!r}: each must be [time_s >= 0, {{...}}]")
        for name, v in k[1].items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise argparse.ArgumentTypeError(f"keyframe {json.dumps(k)}: {name} = {v!r} must be a finite number")
        if keys and t <= keys[-1][0]:
            raise argparse.ArgumentTypeError(f"keyframe times {[kk[0] for kk in keys] + [t]} must be strictly increasing")
        keys.append((float(t), {str(n): float(v) for n, v in k[1].items()}))
    return keys


def clip_source(text: str) -> str:
    """An executor clip to evaluate: a humanoid clip id, a clip file (.npz, .bvh, DeepMimic
    .txt/.json) or a folder of `.npz` clips (`learner.evaluation.executor.evaluate.classify_clip_value`)."""
    from learner.evaluation.executor.evaluate import ClipSelectionError, classify_clip_value

    try:
        classify_clip_value(text)
    except ClipSelectionError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text
