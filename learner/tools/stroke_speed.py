"""`morphmimic stroke-speed`: how fast the base swimmers' strokes carry them, per PD stiffening.

    morphmimic stroke-speed fish manta --gains 1 30

Prints a Markdown table: swimmer, PD gain factor, forward speed, mean joint error and the speed
the swimmer's reference clip asks for (`common.tasks.shape.stroke_speed`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import tyro

from common.config_limits import Limit, at_least, check_limits, validated
from common.tasks.shape.stroke_speed import CLOSE_TRACKING_GAIN, SWIMMERS, stroke_speed
from learner.cli_options import parse_options

Swimmer = Literal["fish", "manta"]
assert tuple(Swimmer.__args__) == SWIMMERS


@validated
@dataclass
class StrokeSpeedOptions:
    presets: tyro.conf.Positional[tuple[Swimmer, ...]] = ()
    """Swimmers to measure (default: both)."""
    gains: tuple[float, ...] = (1.0, 3.0, 10.0, CLOSE_TRACKING_GAIN)
    """PD stiffening factors to measure (kp x gain, kd x sqrt(gain))."""

    LIMITS: ClassVar[dict[str, Limit]] = {"gains": at_least(1, integer=False)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(StrokeSpeedOptions, argv, prog="morphmimic stroke-speed", description=__doc__)
    print("| swimmer | PD gains | speed (m/s) | mean joint error (rad) | clip's speed (m/s) |\n|---|---|---|---|---|")
    for preset in args.presets or SWIMMERS:
        for gain in args.gains:
            s = stroke_speed(preset, gain)
            print(f"| {preset} | x{gain:g} | {s.speed_m_s:.3f} | {s.joint_error_rad:.3f} | {s.clip_speed_m_s:.3f} |")
    return 0
