"""The shape tasks' configurations (Won & Lee 2019, METHOD.md A), one per character family and
ablation variant; `learner/presets.py` pairs each with its PPO, actor and sampler settings.

Every shape task runs 30 Hz control over 480 Hz physics (the characters' stable default; the
paper runs 600 Hz) with 30 s episodes. PD gains follow each shape's torque limits
(`pd_gains_follow_torque`): with the base's gains the smallest bodies' PD sat at its limits.
The manta asks each shape for the speed its own tracked stroke reaches (`swimmer_speed =
"stroke_fit"`, `common.tasks.shape.stroke_model`) and observes its offset from the reference's
course (`observe_course`), on which its episodes end; the fish keeps the length rule. The
swimmers end an episode 1 m off the reference's root (`max_root_deviation`). docs/shape-controllers.md
has the measurements behind each choice.
"""

from __future__ import annotations

from common.tasks.base import TaskConfig
from common.tasks.body_config import BodyConfig
from common.tasks.shape.config import ImitateConfig

SHAPE_TASKS: dict[str, tuple[str, tuple[str, str], bool, str]] = {
    "lower_biped": ("random", ("global_z", "global_x"), False, "lower-body biped walking (MASS walk), random global x per-segment scales"),
    "quadruped": ("random", ("global_z", "global_x"), False, "quadruped trotting (procedural), random global x per-segment scales"),
    "biped": ("leg_arm", ("leg_length", "arm_length"), False, "full biped walking (MASS walk), leg length vs arm length"),
    "fish": ("random", ("global_x", "global_z"), True, "fish swimming (procedural tail beat), random global x per-segment scales"),
    "manta": ("random", ("global_x", "global_y"), True, "manta ray swimming (procedural wing flap), random global x per-segment scales"),
}
"""character -> (shape parameterization, the two parameters of its value map, swimmer, description)."""

VARIANTS: dict[str, str] = {
    "": "adaptive shape sampling (k = 1)",
    "uniform": "ablation: uniform shape sampling (k = 0)",
    "nonorm": "ablation: no reward normalization",
    "fixedshape": "ablation: trained on the base shape only",
}
"""Variant suffix -> what it changes. "uniform" changes the sampler only (`learner/presets.py`)."""


def shape_task(character: str, variant: str = "") -> TaskConfig:
    """The task configuration of `character` (a key of `SHAPE_TASKS`) in `variant` (a key of `VARIANTS`)."""
    if character not in SHAPE_TASKS:
        raise ValueError(f"shape task {character!r} is not one of {sorted(SHAPE_TASKS)}")
    if variant not in VARIANTS:
        raise ValueError(f"shape task variant {variant!r} is not one of {sorted(VARIANTS)}")
    parameterization, _, swimmer, _ = SHAPE_TASKS[character]
    return TaskConfig(
        name=character, control_hz=30.0, sim_hz=480.0, episode_s=30.0,
        body=BodyConfig(parameterization=parameterization, vary_shape=variant != "fixedshape"),
        imitate=ImitateConfig(reward_normalization=variant != "nonorm", max_root_deviation=1.0 if swimmer else 0.0,
                              pd_gains_follow_torque=True,
                              swimmer_speed="stroke_fit" if character == "manta" else "length",
                              observe_course=character == "manta"),
    )
