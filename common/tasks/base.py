"""The environment contract and the MuJoCo stepping helpers every task shares.

Gymnasium-style: `reset(seed, params, clip_id) -> (obs, info)` and
`step(action) -> (obs, reward, terminated, truncated, info)`. `terminated` means the episode
really ended (no bootstrap: a fall); `truncated` means it was cut (time limit, simulator
divergence: bootstrap from the last observation). The two stay apart all the way into GAE.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import mujoco
import numpy as np

from common.params import ParamSpace
from common.tasks.executor_config import ExecutorConfig


@dataclass(frozen=True)
class TaskConfig:
    name: str = "reach"
    """Registered task name (see `common.tasks.registry.TASKS`)."""
    control_hz: float = 25.0
    """Policy decisions per simulated second."""
    sim_hz: float = 500.0
    """Physics steps per simulated second; must be a multiple of control_hz."""
    episode_s: float = 2.0
    """Time limit of an episode in simulated seconds (reached -> truncated)."""
    character: str = ""
    """Shape tasks: character preset (empty: the task name, e.g. `lower_biped`)."""
    parameterization: str = "random"
    """Shape tasks: the character's shape parameterization (`morphmimic character PRESET --list`);
    "random" is Won & Lee's global b_g x per-segment b_l."""
    clip_id: str = ""
    """Shape tasks: reference clip (empty: the character's default, common.tasks.references)."""
    vary_shape: bool = True
    """Shape tasks: False pins the shape to the base character (the no-variation ablation); the
    observation keeps the shape parameters so the policy evaluates on any shape."""
    shape_box_scale: float = 1.0
    """Shape tasks: train on the shape box shrunk toward the base shape by this factor in (0, 1]
    (each bound moves to base + scale * (bound - base)); a curriculum is a run resumed at
    growing scales (0.25, 0.5, 1). Evaluation uses the whole box unless given `--box-scale`."""
    reward_normalization: bool = True
    """Shape tasks: Won & Lee 2019 reward normalization (METHOD.md A, a reconstruction) on/off."""
    task_params: tuple[str, ...] = ()
    """Shape tasks: task parameters sampled per episode beside the shape: "speed", "heading"."""
    speed_range: tuple[float, float] = (0.8, 1.2)
    """Range of the "speed" task parameter: reference playback factor (target velocity scales)."""
    heading_range_rad: tuple[float, float] = (-3.14159, 3.14159)
    """Range of the "heading" task parameter: world yaw of the walking direction, rad."""
    action_scale: float = 0.5
    """Shape tasks: rad of PD-target deviation per unit action (target = q_ref + scale * a)."""
    action_clip: float = 3.0
    """Shape tasks: actions are clipped to [-action_clip, action_clip] before scaling."""
    random_start_phase: bool = True
    """Shape tasks: start each episode at a uniformly random phase of the clip (else at 0)."""
    pd_gains_follow_torque: bool = False
    """Shape tasks: scale each shape's PD gains and rotor inertia by the factor its torque limits
    got (`common.characters.operator.gains_follow_torque_limits`), so small bodies are not
    driven into their limits by the base's stiffness. False: the base's gains on every shape
    (METHOD.md A). The shape presets turn it on (measured in `learner.presets`)."""
    retarget_root_height: str = "contact_set"
    """Walkers: how the retargeted reference's root height is chosen per frame
    (`common.motion.retarget.root_offsets`): "contact_set" (the highest foot of each frame's
    contact set on the floor) or "foot_tracks" (continuous across contact-set changes: a
    quadruped whose diagonal pairs differ in length does not drop its root at each switch)."""
    shin_contact_is_fall: bool = True
    """Walkers: False lets the segment above each foot (a quadruped's shank) touch the floor
    without it counting as a fall; the trunk, head and thighs still end the episode."""
    max_root_deviation: float = 0.0
    """Swimmers: terminate (as a fall) when the root is this many body lengths from the
    reference root; 0 turns it off."""
    reward_weights: tuple[float, ...] = ()
    """Shape tasks: w1..w6 (empty: the character's row of METHOD.md A's table)."""
    reward_sensitivities: tuple[float, ...] = (0.02, 0.5, 0.2, 0.2, 0.05, 0.1)
    """Shape tasks: s1..s6 (METHOD.md A)."""
    executor: ExecutorConfig = ExecutorConfig()
    """The `executor` task's settings (UniCon 2020, METHOD.md B): `--task.executor.tau 2` etc."""
    character_cache: int = 8
    """Shape tasks: compiled characters + retargeted references kept per environment (LRU):
    a repeated shape (the MCMC buffer repeats them) skips the 15-100 ms rebuild."""

    @property
    def substeps(self) -> int:
        ratio = self.sim_hz / self.control_hz
        if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
            raise ValueError(f"sim_hz={self.sim_hz} must be a positive multiple of control_hz={self.control_hz}")
        return int(round(ratio))

    @property
    def episode_steps(self) -> int:
        return max(1, int(round(self.episode_s * self.control_hz)))


class Env(Protocol):
    obs_dim: int
    act_dim: int
    space: ParamSpace

    def reset(self, seed: int | None, params: np.ndarray, clip_id: str | None = None) -> tuple[np.ndarray, dict]: ...

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]: ...


_DIVERGENCE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADCTRL,
)


def step_physics(model: mujoco.MjModel, data: mujoco.MjData, substeps: int) -> bool:
    """Advance `substeps` physics steps; return True if MuJoCo diverged.

    NOTE: MuJoCo resets `MjData` silently when the state blows up; the only trace is the
    warning counters, so they are compared before and after (DESIGN.md "Environments").
    """
    before = sum(int(data.warning[w].number) for w in _DIVERGENCE_WARNINGS)
    mujoco.mj_step(model, data, nstep=substeps)
    after = sum(int(data.warning[w].number) for w in _DIVERGENCE_WARNINGS)
    return after != before or not np.isfinite(data.qpos).all()
