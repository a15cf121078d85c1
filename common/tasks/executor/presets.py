"""The executor's task configurations (UniCon 2020, METHOD.md B), one per variant;
`learner/presets.py` pairs each with its PPO, actor and sampler settings.

The executor runs on the DeepMimic humanoid over the train split of every clip that plays on
it: agent-centric observation with tau = 1, the five-term reward, per-term termination,
reactive state initialization, 60 Hz control with 4 substeps (240 Hz physics), the motion
balancer's clip draws, 20 s episodes.

The "shape" variant is "track" with `vary_shape` on (issue 55 item 1): every episode draws a body
from Won & Lee's height x thickness box (METHOD.md A), the clip is retargeted onto it and the
position terms are normalized by its size (`bodies.py`, `rewards.size_normalized_errors`).

The "pd" variant (the one trained and shipped) differs from UniCon where measurements said so
(docs/executor.md has each comparison): PD targets instead of torques; the PD damps toward the
next frame's joint velocity (`pd_velocity_target`); ankles, shoulders and elbows carry a rotor
inertia of 0.1 kg m^2 (`ankle_armature`, `arm_armature`); half of the episodes start on the
tracked frame with the rule from the first step (`on_frame_share`). Every variant watches the
four pose terms for termination (`terminate_on`); joint velocity stays in the reward.
"""

from __future__ import annotations

from common.tasks.base import TaskConfig
from common.tasks.body_config import BodyConfig
from common.tasks.executor.config import ExecutorConfig
from common.tasks.executor.rewards import POSE_TERMS, TERMS

VARIANTS: dict[str, str] = {
    "": "torque, per-term termination, balancer, reactive initialization",
    "pd": "ablation: PD targets instead of torques",
    "track": "PD targets, trained on the rule it is evaluated by, over the whole library (issue 52's recipe)",
    "shape": "the track recipe over the humanoid's shapes (height x thickness), each clip retargeted onto each body",
    "noterm": "ablation: sum rule, no per-term termination",
    "uniform": "ablation: uniform clip draws, no balancer",
    "norsis": "ablation: no reactive initialization",
}
"""Variant suffix -> what it changes."""


def executor_task(variant: str = "") -> TaskConfig:
    """The executor's task configuration in `variant` (a key of `VARIANTS`)."""
    if variant not in VARIANTS:
        raise ValueError(f"executor variant {variant!r} is not one of {sorted(VARIANTS)}")
    if variant in ("track", "shape"):
        return TaskConfig(name="executor", control_hz=60.0, sim_hz=240.0, episode_s=20.0,
                          body=BodyConfig(parameterization="height_thickness", vary_shape=variant == "shape"),
                          executor=track_config())
    ex = ExecutorConfig(
        actuation="pd" if variant == "pd" else "torque",
        pd_velocity_target=variant == "pd",
        ankle_armature=0.1 if variant == "pd" else 0.01,
        arm_armature=0.1 if variant == "pd" else 0.01,
        termination="sum" if variant == "noterm" else "per_term",
        reactive_init=variant != "norsis",
        clip_draws="uniform" if variant == "uniform" else "balancer",
        terminate_on=POSE_TERMS,
        on_frame_share=0.5 if variant == "pd" else 0.0,
    )
    return TaskConfig(name="executor", control_hz=60.0, sim_hz=240.0, episode_s=20.0,
                      body=BodyConfig(parameterization="height_thickness", vary_shape=False), executor=ex)


def track_config() -> ExecutorConfig:
    """The executor trained on the rule it is evaluated by (the "track" variant): what the
    evaluation watches is what ends a training episode, and the references are cleaned first.

    - References cleaned once (`docs/experiments/2026-12-06-executor-reference-cleaning.md`):
      tracks low-pass filtered at 7 Hz, lifted out of the floor, PD targets clamped to widened ranges.
    - Rule: all five terms, joint velocity included, from the first step on 80% of starts, which
      are on the tracked frame exactly as the evaluation starts; the other 20% start reactively
      (UniCon 5.2) and the rule waits for them only until every term is back above alpha
      (`catch_up_ends = "on_track"`, at most `catch_up_steps`).
    - At a clip's end the episode truncates (and bootstraps) instead of rescheduling a random
      clip under a new wait: every start is then the sampler's draw.
    - An action-rate penalty (w = 0.1 on the mean squared change, mjlab's action_rate_l2) and the
      previous action in the observation.
    - The whole library: DeepMimic, MASS and the Bandai Namco takes (CC BY-NC 4.0)."""
    return ExecutorConfig(
        library="full", actuation="pd", pd_velocity_target=True, ankle_armature=0.1, arm_armature=0.1,
        reference_filter_hz=7.0, reference_floor=True, pd_target_range="widened",
        terminate_on=TERMS, on_frame_share=0.8, catch_up_ends="on_track", at_clip_end="stop",
        action_rate_weight=0.1, previous_action_obs=True,
    )
