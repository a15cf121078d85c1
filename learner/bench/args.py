"""Command-line value types the benchmarks share."""

from __future__ import annotations

import argparse


def positive_ints(text: str) -> list[int]:
    """`--widths 128,256`-style lists: comma-separated integers of at least 1, else argparse's error (exit 2)."""
    try:
        values = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        values = []
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give comma-separated positive integers, e.g. 1,2,4,8")
    return values
