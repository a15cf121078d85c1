"""The environment contract and the MuJoCo stepping helpers every task shares.

Gymnasium-style: `reset(seed, params, clip_id) -> (obs, info)` and
`step(action) -> (obs, reward, terminated, truncated, info)`. `terminated` means the episode
really ended (no bootstrap: a fall, a task's own end, a simulator divergence); `truncated` means
it was cut (the time limit: bootstrap from the last observation). The two stay apart all the
way into GAE. A divergence terminates because its next state is garbage to bootstrap from and
the policy's actions are what blow the simulation up (METHOD.md A lists simulation failure
among the terminations): every task returns `diverged_step(...)` for it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import mujoco
import numpy as np

from common.config_limits import Limit, between, check_limits, validated
from common.params import ParamSpace
from common.tasks.body_config import BodyConfig
from common.tasks.executor.config import ExecutorConfig
from common.tasks.shape.config import ImitateConfig


@dataclass(frozen=True)
@validated
class TaskConfig:
    """What every task shares (its name, rates and horizon) and one section per kind of task:
    `body` (the simulated body and its shape variation), `imitate` (the shape tasks), `executor`
    (UniCon's motion executor). A task reads only its own section and `body`."""

    name: str = "reach"
    """Registered task name (see `common.tasks.registry.TASKS`)."""
    control_hz: float = 25.0
    """Policy decisions per simulated second."""
    sim_hz: float = 500.0
    """Physics steps per simulated second; must be a multiple of control_hz."""
    episode_s: float = 2.0
    """Time limit of an episode in simulated seconds (reached -> truncated)."""
    body: BodyConfig = BodyConfig()
    """The body and its shape variation: `--task.body.parameterization leg_arm` etc."""
    imitate: ImitateConfig = ImitateConfig()
    """The shape tasks' settings (Won & Lee 2019, METHOD.md A): `--task.imitate.clip-id` etc."""
    executor: ExecutorConfig = ExecutorConfig()
    """The `executor` task's settings (UniCon 2020, METHOD.md B): `--task.executor.tau 2` etc."""

    FLAG_PREFIX: ClassVar[str] = "task"
    LIMITS: ClassVar[dict[str, Limit]] = {
        "control_hz": between(0, 10_000, lo_open=True), "sim_hz": between(0, 100_000, lo_open=True),
        "episode_s": between(0, 1e6, lo_open=True),
    }
    """Allowed values of the numeric fields (`common.config_limits`)."""

    def validate(self) -> None:
        """ValueError naming the first value outside what is allowed."""
        check_limits(self)

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


_DIVERGENCE_WARNINGS = [
    int(mujoco.mjtWarning.mjWARN_BADQACC),
    int(mujoco.mjtWarning.mjWARN_BADQVEL),
    int(mujoco.mjtWarning.mjWARN_BADQPOS),
    int(mujoco.mjtWarning.mjWARN_BADCTRL),
]


def step_physics(model: mujoco.MjModel, data: mujoco.MjData, substeps: int) -> bool:
    """Advance `substeps` physics steps; return True if MuJoCo diverged.

    NOTE: MuJoCo resets `MjData` silently when the state blows up; the only trace is the
    warning counters, so they are compared before and after.
    """
    # NOTE: the counters are read as one array (`warning.number`), not one wrapper per warning.
    before = int(data.warning.number[_DIVERGENCE_WARNINGS].sum())
    mujoco.mj_step(model, data, nstep=substeps)
    after = int(data.warning.number[_DIVERGENCE_WARNINGS].sum())
    return after != before or not np.isfinite(data.qpos).all()


def diverged_step(obs_dim: int, **info: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
    """What a task's `step` returns when `step_physics` reported a divergence: terminated, not
    truncated (no bootstrap), reward 0, a zero observation (the state is garbage) and `info`
    with `diverged=True`, `fell=False` (a divergence is counted apart from falls) and `info`."""
    return np.zeros(obs_dim, np.float32), 0.0, True, False, {"diverged": True, "fell": False, **info}
