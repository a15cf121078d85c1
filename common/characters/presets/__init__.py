"""Base characters B, one module per character; `PRESETS` maps a preset name to its builder."""

from __future__ import annotations

import importlib
from collections.abc import Callable

from common.characters.builder import BaseCharacter


def _lazy(module: str) -> Callable[[float], BaseCharacter]:
    def build(timestep_s: float) -> BaseCharacter:
        return importlib.import_module(f"common.characters.presets.{module}").build(timestep_s)

    return build


PRESETS: dict[str, Callable[[float], BaseCharacter]] = {
    "humanoid": _lazy("humanoid"),
    "biped": _lazy("biped"),
    "lower_biped": _lazy("lower_biped"),
    "quadruped": _lazy("quadruped"),
    "fish": _lazy("fish"),
    "manta": _lazy("manta"),
}
