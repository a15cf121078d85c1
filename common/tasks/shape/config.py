"""`ImitateConfig`: the settings of the shape tasks, one clip imitated by bodies of many shapes
(Won & Lee 2019, METHOD.md A; `common.tasks.shape.env`): `--task.imitate.no-reward-normalization`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import ClassVar

from common.config_limits import FINITE, Limit, above, at_least, check_limits, validated
from common.motion.retarget_config import RetargetConfig

TASK_PARAMS = ("speed", "heading")
"""Task parameters a shape task can sample per episode beside the shape."""
SWIMMER_SPEED_RULES = ("length", "stroke_fit")
"""How a swimmer's target speed follows its shape (`ImitateConfig.swimmer_speed`)."""


@dataclass(frozen=True)
@validated
class ImitateConfig:
    clip_id: str = ""
    """Reference clip (empty: the character's default, common.tasks.shape.references)."""
    reward_normalization: bool = True
    """Won & Lee 2019 reward normalization (METHOD.md A, a reconstruction) on/off."""
    task_params: tuple[str, ...] = ()
    """Task parameters sampled per episode beside the shape: "speed", "heading"."""
    speed_range: tuple[float, float] = (0.8, 1.2)
    """Range of the "speed" task parameter: reference playback factor (target velocity scales)."""
    heading_range_rad: tuple[float, float] = (-3.14159, 3.14159)
    """Range of the "heading" task parameter: world yaw of the walking direction, rad."""
    action_scale: float = 0.5
    """Rad of PD-target deviation per unit action (target = q_ref + scale * a)."""
    action_clip: float = 3.0
    """Actions are clipped to [-action_clip, action_clip] before scaling."""
    random_start_phase: bool = True
    """Start each episode at a uniformly random phase of the clip (else at 0)."""
    pd_gains_follow_torque: bool = False
    """Scale each shape's PD gains and rotor inertia by the factor its torque limits
    got (`common.characters.operator.gains_follow_torque_limits`), so small bodies are not
    driven into their limits by the base's stiffness. False: the base's gains on every shape
    (METHOD.md A). The shape presets turn it on (measured in `learner.presets`)."""
    retarget: RetargetConfig = field(default_factory=RetargetConfig)
    """Walkers: how the clip is retargeted onto each shape (`--task.imitate.retarget.<field>`).
    `root_height` chooses the reference's root height per frame
    (`common.motion.root_height.root_offsets`): "contact_set" (the highest foot of each frame's
    contact set on the floor), "foot_tracks" (continuous across contact-set changes: a
    quadruped whose diagonal pairs differ in length does not drop its root at each switch) or
    "contact_smooth" ("contact_set" lowered where needed so the root moves at most 0.5 m/s
    across a switch: continuous, and the longer leg bends only around the switches).
    `body_clearance_m` lifts the reference's root where it brings a body other than the feet
    closer to the floor than this (m; `common.motion.retarget.clearance_lift`), so the
    reference never asks for a fall (by this task's rule); 0: off. On the lower biped's 300
    evaluation shapes the unlifted walk put a shin within 5 mm of the floor on 8, and all 8 fell
    with `lower_biped-curriculum` (`morphmimic references`, `morphmimic evaluate`).
    `clearance_shins_may_touch` is not set here: it follows `shin_contact_is_fall`."""
    shin_contact_is_fall: bool = True
    """Walkers: False lets the segment above each foot (a quadruped's shank) touch the floor
    without it counting as a fall; the trunk, head and thighs still end the episode. Every
    preset keeps Won & Lee's rule (True). The clearance lift (`retarget.body_clearance_m`)
    follows the same rule."""
    max_root_deviation: float = 0.0
    """Swimmers: terminate (as a fall) when the root is this many body lengths off the
    reference's course (sideways or vertically; lagging or leading along it is not a fall, see
    `ImitateEnv.off_course_m`); 0 turns it off."""
    observe_course: bool = False
    """Swimmers: the observation ends with the root's offset from the reference's course (the
    quantity `max_root_deviation` ends episodes on: sideways, vertical and, from the heading
    error, along; in the root's heading frame, in body lengths), which it otherwise lacks
    (sideways drift is invisible to it). Three more inputs: a checkpoint trained without it
    resumes only with `--task.imitate.no-observe-course`."""
    swimmer_speed: str = "length"
    """Swimmers, with reward normalization: the target speed of a shape. "length": the clip's
    speed times the body length over the base's (the leg-length rule of METHOD.md A with the
    length for the legs); "stroke_fit": that times what the shape's own tracked stroke reaches
    over it, from the fitted model `common/data/stroke_speed/<preset>.json`
    (`learner.tools.stroke_fit`; a deviation from the paper)."""
    reward_weights: tuple[float, ...] = ()
    """W1..w6 (empty: the character's row of METHOD.md A's table)."""
    reward_sensitivities: tuple[float, ...] = (0.02, 0.5, 0.2, 0.2, 0.05, 0.1)
    """S1..s6 (METHOD.md A)."""
    character_cache: int = 8
    """Compiled characters + retargeted references kept per environment (LRU):
    a repeated shape (the MCMC buffer repeats them) skips the 15-100 ms rebuild."""

    FLAG_PREFIX: ClassVar[str] = "task.imitate"
    LIMITS: ClassVar[dict[str, Limit]] = {
        "speed_range": above(0), "heading_range_rad": FINITE, "action_scale": above(0), "action_clip": above(0),
        "max_root_deviation": at_least(0, False), "reward_weights": at_least(0, False), "reward_sensitivities": above(0),
        "character_cache": at_least(1),
    }
    """Allowed values of the numeric fields (`common.config_limits`)."""

    def validate(self) -> None:
        """ValueError naming the first value outside what is allowed."""
        check_limits(self)
        for name in ("speed_range", "heading_range_rad"):
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ValueError(f"--task.imitate.{name.replace('_', '-')} = {(lo, hi)} must be low <= high")
        bad = [p for p in self.task_params if p not in TASK_PARAMS]
        if bad:
            raise ValueError(f"--task.imitate.task-params = {self.task_params}: give any of {', '.join(TASK_PARAMS)}")
        if self.swimmer_speed not in SWIMMER_SPEED_RULES:
            raise ValueError(f"--task.imitate.swimmer-speed = {self.swimmer_speed!r}: give {', '.join(SWIMMER_SPEED_RULES)}")
        if self.retarget.clearance_shins_may_touch:
            raise ValueError("--task.imitate.retarget.clearance-shins-may-touch is set by the fall rule: "
                             "give --task.imitate.no-shin-contact-is-fall instead")

    def retarget_for_task(self) -> RetargetConfig:
        """`retarget` with the clearance lift under this task's fall rule (`shin_contact_is_fall`)."""
        return dataclasses.replace(self.retarget, clearance_shins_may_touch=not self.shin_contact_is_fall)

