"""`BodyConfig`: the body a task simulates and how its shape varies (Won & Lee 2019, METHOD.md A).

Shared by the shape tasks (`imitate`) and the executor, whose humanoid stays at its base shape
unless `--task.body.vary-shape` (the `executor-shape` preset) draws a body beside each clip;
`common.tasks.shape_params` turns it into the episode parameters of either.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from common.config_limits import Limit, between, check_limits, validated


@dataclass(frozen=True)
@validated
class BodyConfig:
    character: str = ""
    """Character preset (empty: the task name, e.g. `lower_biped`)."""
    parameterization: str = "random"
    """The character's shape parameterization (`morphmimic character PRESET --list`);
    "random" is Won & Lee's global b_g x per-segment b_l."""
    vary_shape: bool = True
    """False pins the shape to the base character (the no-variation ablation); the
    observation keeps the shape parameters so the policy evaluates on any shape."""
    shape_box_scale: float = 1.0
    """Train on the shape box shrunk toward the base shape by this factor in (0, 1]
    (each bound moves to base + scale * (bound - base)); a curriculum is a run resumed at
    growing scales (0.25, 0.5, 1). Evaluation uses the whole box unless given `--box-scale`."""


    FLAG_PREFIX: ClassVar[str] = "task.body"
    LIMITS: ClassVar[dict[str, Limit]] = {
        "shape_box_scale": between(0, 1, lo_open=True),
    }
    """Allowed values of the numeric fields (`common.config_limits`)."""

    def validate(self) -> None:
        """ValueError naming the first value outside what is allowed."""
        check_limits(self)
        if not 0.0 < self.shape_box_scale <= 1.0:
            raise ValueError(f"--task.body.shape-box-scale = {self.shape_box_scale} must be in (0, 1] (1: the whole box)")
