"""How fast a swimmer's stroke carries its body: the speed its reference clip may ask for.

    morphmimic stroke-speed fish manta      # the base bodies, PD x1 (zero action) and stiffened

Won & Lee 2019 (METHOD.md A) drive the fish and the manta ray with hand-made sinusoidal
keyframes whose root moves forward; in MuJoCo's fluid the root's speed is not free but what the
stroke's thrust gives. A reference whose root runs slower than its own stroke pushes is a
contradiction the policy cannot resolve: the imitation terms reward tracking the stroke, and a
tracked stroke outswims the root (a swimmer falls only off its reference's course, not by lagging
or leading along it: `ImitateEnv.off_course_m`). So the clip's
speed is measured with the stroke tracked closely: the base body's PD gains stiffened `gain_scale` times (kp x s, kd x sqrt(s)), its torque limits kept (what a
policy can reach), zero action, from `start_s` to `stop_s`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

SWIMMERS = ("fish", "manta")
CLOSE_TRACKING_GAIN = 30.0
"""PD stiffening that tracks the base swimmers' strokes to within 0.01 rad (mean over joints)."""


@dataclass(frozen=True)
class StrokeSpeed:
    preset: str
    gain_scale: float
    speed_m_s: float
    joint_error_rad: float  # mean |joint angle - reference| over the measured window
    clip_speed_m_s: float  # what the task's clip asks for


def stroke_speed(preset: str, gain_scale: float = CLOSE_TRACKING_GAIN, start_s: float = 5.0,
                 stop_s: float = 20.0, params: np.ndarray | None = None) -> StrokeSpeed:
    """Forward speed of the `preset` swimmer (the base body, or the shape `params` of the
    preset's parameterization) tracking its stroke with PD gains x `gain_scale` and zero action,
    averaged over [start_s, stop_s] (see the module docstring). `clip_speed_m_s` is then the
    speed of the reference the task retargets to that body."""
    if preset not in SWIMMERS:
        raise ValueError(f"stroke speed: {preset!r} is not a swimmer; choose one of {SWIMMERS}")
    if not (np.isfinite(gain_scale) and gain_scale >= 1.0):
        raise ValueError(f"stroke speed: gain scale {gain_scale} must be a finite number >= 1")
    if not (0.0 <= start_s and start_s + 1.0 <= stop_s <= 60.0):
        raise ValueError(f"stroke speed: window [{start_s}, {stop_s}] s must satisfy 0 <= start, start + 1 <= stop <= 60")
    # lazy: start-up time of morphmimic stroke-speed --help (mujoco via the tasks)
    from common.tasks.registry import make_env, task_space
    from common.tasks.shape.presets import shape_task  # lazy: as above

    task = shape_task(preset)
    task = dataclasses.replace(task, episode_s=stop_s + 1.0, imitate=dataclasses.replace(
        task.imitate, max_root_deviation=0.0, random_start_phase=False, swimmer_speed="length"))
    env = make_env(task, seed=0)
    env.reset(0, task_space(task).default_array if params is None else params)
    m = env.model
    m.actuator_gainprm[:, 0] *= gain_scale
    m.actuator_biasprm[:, 1] *= gain_scale
    m.actuator_biasprm[:, 2] *= np.sqrt(gain_scale)
    start, stop = round(start_s * task.control_hz), round(stop_s * task.control_hz)
    x0, errors = float(env.data.qpos[0]), []
    for k in range(1, stop + 1):
        env.step(np.zeros(env.act_dim))
        if k == start:
            x0 = float(env.data.qpos[0])
        if k > start:
            errors.append(float(np.abs(env.layout.to_vector(env.data.qpos) - env.ref_joints[0]).mean()))
    ref = env.motion.qpos_frames[:, 0]  # the reference root as retargeted to this body
    return StrokeSpeed(preset, gain_scale, (float(env.data.qpos[0]) - x0) / (stop_s - start_s), float(np.mean(errors)),
                       float((ref[-1] - ref[0]) / env.motion.duration_s))
