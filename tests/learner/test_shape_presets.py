"""The shape-task presets: every character has the adaptive preset and its three ablations,
each differing from it in exactly the one thing it ablates."""

from __future__ import annotations

import pytest

from common.tasks.registry import task_space
from learner.presets import PRESETS

CHARACTERS = ["lower_biped", "quadruped", "biped", "fish", "manta"]


@pytest.mark.parametrize("character", CHARACTERS)
def test_presets_and_their_ablations(character: str) -> None:
    base = PRESETS[character][1]
    assert base.task.name == character and base.sampler.k > 0
    assert base.task.control_hz == 30.0 and base.task.episode_s == 30.0 and base.ppo.gamma == 0.95
    assert base.policy.hidden == (128, 128, 128) and base.steps_per_iteration == 4096
    uniform, nonorm, fixed = (PRESETS[f"{character}-{v}"][1] for v in ("uniform", "nonorm", "fixedshape"))
    assert uniform.sampler.k == 0 and uniform.task == base.task
    assert not nonorm.task.imitate.reward_normalization and nonorm.sampler == base.sampler
    assert not fixed.task.body.vary_shape and fixed.sampler == base.sampler
    space = task_space(base.task)
    assert all(n in space.names for n in base.sampler.plot_params)
    assert (space.high_array > space.low_array).all()


def test_random_shapes_follow_the_paper_ranges() -> None:
    """Won & Lee 2019: global b_g in [0.5, 1.5]^3, per-segment b_l in [0.7, 1.2]^3."""
    space = task_space(PRESETS["lower_biped"][1].task)
    assert space.low[:3] == (0.5, 0.5, 0.5) and space.high[:3] == (1.5, 1.5, 1.5)
    assert set(space.low[3:]) == {0.7} and set(space.high[3:]) == {1.2}
    leg_arm = task_space(PRESETS["biped"][1].task)
    assert leg_arm.names == ("leg_length", "arm_length")
    assert leg_arm.low == (0.5, 0.5) and leg_arm.high == (2.0, 1.5)
