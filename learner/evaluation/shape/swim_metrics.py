"""What a swimmer's evaluation measures besides Won & Lee's task reward (METHOD.md A, the fish
and the manta ray "with lift and drag in water").

A walker's quality is mostly whether it stays up. A swimmer in MuJoCo's fluid has no floor to
fall on (its episode ends as a "fall" only when its root is more than `max_root_deviation` body
lengths off the reference's course, sideways or vertically), so its evaluation (`morphmimic evaluate` on a `fish` or `manta`
checkpoint) also reports, per episode and averaged over the shapes:

- **speed error**: | |v| - |v_target| | / |v_target| in %, where v is the centre of mass's
  horizontal velocity averaged over the task reward's 2 s window (`ImitateEnv.com_velocity_avg`)
  and v_target the task's horizontal target velocity (the clip's cycle velocity, scaled for
  the body: by its length, and under `--task.imitate.swimmer-speed stroke_fit` by the speed its
  own tracked stroke reaches, `learner.tools.stroke_fit`); a climb or a dive is not counted here
  but in the root's distance. The error against the length rule's target alone is reported
  beside it (`swim_speed_error_length_pct`), so runs under either rule compare;
- **heading error**: the angle in degrees between v and v_target in the horizontal plane;
- **upright %**: the share of control steps on which the root's up axis is within
  `UPRIGHT_DEG` of the reference root's up axis (a fish or manta rolled on its side or belly up
  swims, but not as the clip does);
- **mean speed** (m/s), beside the mean target speed.

The first 2 s of an episode are left out of the speed and heading errors: the window starts
at rest and would count the start-up as error. These metrics are this project's own; the paper
reports only task achievement and falls for its swimmers.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from common.tasks.shape.env import COM_WINDOW_S
from common.tasks.observations import quat_to_mat

UPRIGHT_DEG = 45.0
"""Largest angle between the root's up axis and the reference root's that counts as upright."""

WARMUP_S = COM_WINDOW_S
"""Seconds at the start of an episode left out of the speed and heading errors (the COM window)."""


def target_rule(env: Any) -> str:
    """How the swimmer's target speed was set in this evaluation: "length", "stroke_fit <model
    digest>" (`learner.tools.stroke_fit`), or unscaled without reward normalization."""
    if not env.cfg.imitate.reward_normalization:
        return "unscaled (no reward normalization)"
    model = getattr(env, "stroke_model", None)
    return "length" if model is None else f"stroke_fit {model.digest}"


class SwimTracker:
    """Called after every control step of an evaluation episode (`episodes.run_episode`'s
    `on_step`); `result()` gives the episode's swim metrics."""

    def __init__(self) -> None:
        self.speed_err: list[float] = []
        self.speed_err_length: list[float] = []
        self.heading_err: list[float] = []
        self.speed: list[float] = []
        self.target: list[float] = []
        self.upright = 0
        self.steps = 0

    def __call__(self, env: Any, k: int) -> None:
        self.steps += 1
        up = quat_to_mat(np.asarray(env.data.qpos[3:7]))[:, 2]
        up_ref = quat_to_mat(np.asarray(env.ref_q[0][3:7]))[:, 2]
        if float(np.dot(up, up_ref)) >= math.cos(math.radians(UPRIGHT_DEG)):
            self.upright += 1
        if k * env.dt < WARMUP_S:
            return
        v, vt = env.com_velocity_avg(), env.target_velocity()
        speed, target = float(np.linalg.norm(v)), float(np.linalg.norm(vt))
        self.speed.append(speed)
        self.target.append(target)
        if target > 1e-9:
            self.speed_err.append(100.0 * abs(speed - target) / target)
            length_target = target / env.norm.speed_factor if env.cfg.imitate.reward_normalization else target
            self.speed_err_length.append(100.0 * abs(speed - length_target) / length_target)
            cross, dot = vt[0] * v[1] - vt[1] * v[0], float(np.dot(v, vt))
            self.heading_err.append(math.degrees(abs(math.atan2(cross, dot))))

    def result(self) -> dict[str, float | None]:
        """The episode's figures; None where an episode ended inside the warm-up (JSON has no NaN)."""
        def mean(xs: list[float]) -> float | None:
            return float(np.mean(xs)) if xs else None

        return {"swim_speed_error_pct": mean(self.speed_err), "swim_speed_error_length_pct": mean(self.speed_err_length),
                "swim_heading_error_deg": mean(self.heading_err),
                "swim_upright_pct": 100.0 * self.upright / max(1, self.steps),
                "swim_speed_m_s": mean(self.speed), "swim_target_speed_m_s": mean(self.target)}


SWIM_FIELDS = ("swim_speed_error_pct", "swim_speed_error_length_pct", "swim_heading_error_deg", "swim_upright_pct", "swim_speed_m_s",
               "swim_target_speed_m_s")


def summarize_swim(results: list[dict]) -> dict[str, float]:
    """Each swim metric averaged over the episodes that have it (an episode shorter than the
    warm-up has no speed error: None); {} for a walker's results."""
    out = {}
    for field in SWIM_FIELDS:
        xs = [r[field] for r in results if r.get(field) is not None and np.isfinite(r[field])]
        if xs:
            out[field] = float(np.mean(xs))
    return out
