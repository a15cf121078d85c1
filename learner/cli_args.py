"""argparse `type=` converters of the evaluation commands (evaluate, ablation, learning_curve,
morph_demo): each turns bad input into a usage error that names the value and what is allowed,
before any checkpoint is loaded or any episode run."""

from __future__ import annotations

import argparse
import math

from learner.eval_core import check_box_scale


def _number(text: str, kind: type, allowed: str) -> float:
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}; "
                                         f"it must be {allowed}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} must be {allowed}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1 (shape counts, worker counts, strides)."""
    value = _number(text, int, "an integer >= 1")
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be an integer >= 1")
    return value


def seed(text: str) -> int:
    """A random seed: an integer >= 0 (numpy's generators refuse negative seeds)."""
    value = _number(text, int, "an integer >= 0")
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be an integer >= 0")
    return value


def percent(text: str) -> float:
    """A percentage in [0, 100] (a fall-down target)."""
    value = _number(text, float, "a number in [0, 100]")
    if not 0.0 <= value <= 100.0:
        raise argparse.ArgumentTypeError(f"{text!r} must be a number in [0, 100]")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0 (episode lengths in seconds)."""
    value = _number(text, float, "a finite number > 0")
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be a finite number > 0")
    return value


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
