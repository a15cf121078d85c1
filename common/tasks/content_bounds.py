"""What one control step of a task can hold: its reward range, how large an observation can
be, and its episode horizon.

Each task declares its bounds beside its reward (`content_bounds(cfg)` on the environment class,
read through `common.tasks.registry.task_bounds`), derived from what the reward function can
return. The learner holds every unroll to them before it reaches the observation normalizer, the
value targets, the counters or the sampler (`learner/unroll_bounds.py`): an observation of 3e38
or a reward of 1e30 passes the codec (they are finite float32) but no honest actor of the task
can send it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

OBS_MAX_ABS_LIMIT = 1e6
"""The largest observation magnitude a task may declare: the character tasks' velocity features
stay in the hundreds under a random policy (the executor's largest was 372), and the observation
normalizer clips raw values to this before folding them in (`ObsNormalizer.RAW_LIMIT`)."""


@dataclass(frozen=True)
class ContentBounds:
    """Per-step bounds of one task's unrolls (every number in the task's own units)."""

    reward_min: float
    """Lowest reward one control step can earn (a divergence earns 0, so this is at most 0)."""
    reward_max: float
    """Highest reward one control step can earn."""
    obs_max_abs: float
    """No observation component exceeds this in magnitude (before normalization)."""
    episode_steps: int
    """No episode is longer than this many control steps (the time limit truncates it)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.reward_min) and math.isfinite(self.reward_max) and self.reward_min <= 0 <= self.reward_max):
            raise ValueError(f"reward bounds [{self.reward_min}, {self.reward_max}]: give finite bounds around 0 "
                             "(a diverged step earns 0)")
        if not 0 < self.obs_max_abs <= OBS_MAX_ABS_LIMIT:
            raise ValueError(f"obs_max_abs = {self.obs_max_abs}; allowed: (0, {OBS_MAX_ABS_LIMIT:g}]")
        if self.episode_steps < 1:
            raise ValueError(f"episode_steps = {self.episode_steps}; allowed: at least 1")

    @property
    def reward_scale(self) -> float:
        """The largest reward magnitude, for tolerances."""
        return max(abs(self.reward_min), abs(self.reward_max), 1.0)
