"""Every registered task as a Gymnasium environment: `gymnasium.make("morphmimic/<Task>-v0")`.

Importing this module registers one id per task of `common.tasks.registry.TASKS`, the task's
name in CamelCase: `morphmimic/Reach-v0`, `morphmimic/LowerBiped-v0`, `morphmimic/Biped-v0`,
`morphmimic/Quadruped-v0`, `morphmimic/Fish-v0`, `morphmimic/Manta-v0`, `morphmimic/Executor-v0`.
Gymnasium 1.x loads no plugins by entry point (0.x did), so either import it first or name it in
the id, which makes Gymnasium import it: `gymnasium.make("common.tasks.gym:morphmimic/Reach-v0")`.

    import gymnasium, common.tasks.gym
    env = gymnasium.make("morphmimic/LowerBiped-v0", render_mode="rgb_array")
    obs, info = env.reset(seed=0, options={"shape": {"global_z": 1.1}})

- The configuration is the task part of the task's training preset (`default_config`);
  `gymnasium.make(id, config=TaskConfig(...))` replaces it (its `name` must be the task's).
- `reset(seed=, options=)`: the episode's parameters (a body shape, a reach target, task
  parameters) are a uniform draw over the task's parameter space unless `options` gives them:
  `{"params": [...]}` (every value, in `param_space(...).names` order, or a mapping of some of
  them), `{"shape": {"global_z": 1.1}}` (a mapping; the rest take their defaults). The
  executor also takes `{"clip_id": "humanoid3d_walk"}` (a clip of its `executor.split`, the
  train split by default; else the motion balancer draws one) and `{"start_s": 0.5}`; a shape
  task takes only its own clip.
- `step` returns the task's own `terminated` (a fall, a tracking failure, a divergence),
  `truncated` (its time limit, the executor's schedule ending) and `info`; no `TimeLimit`
  wrapper is added, since the tasks cut their episodes themselves.
- Spaces: observations are unbounded float32 vectors (the policy normalises them); actions are
  bounded where the task clips them, so an action outside the box acts as its nearest point.
- `render()` with `render_mode="rgb_array"`: an `[height, width, 3]` uint8 frame from MuJoCo's
  offscreen renderer, a camera following the body's root (the arm seen from above).
"""

from __future__ import annotations

import inspect
from typing import Any, Mapping

import gymnasium
import mujoco
import numpy as np
from gymnasium import spaces

from common.offscreen_gl import use_offscreen_context
from common.tasks.base import TaskConfig
from common.tasks.executor.presets import executor_task
from common.tasks.registry import TASKS, make_env, task_entry
from common.tasks.shape.presets import shape_task

NAMESPACE = "morphmimic"
VERSION = 0
OPTIONS = ("params", "shape", "clip_id", "start_s")
"""The keys `reset(options=...)` takes."""
EXECUTOR_PD_ACTION_CLIP = 3.0
"""`ExecutorEnv.step` clips PD actions (target offsets, before `pd_action_scale`) to +-3."""


def env_id(task: str) -> str:
    """The Gymnasium id of registered task `task`: `lower_biped` -> `morphmimic/LowerBiped-v0`."""
    return f"{NAMESPACE}/{''.join(part.capitalize() for part in task.split('_'))}-v{VERSION}"


def default_config(task: str) -> TaskConfig:
    """The task part of `task`'s training preset (`--preset <task>`): the shape tasks' from
    `shape_task`, the executor's from `executor_task` (torque), reach's the defaults."""
    family = task_entry(task).family
    if family == "shape":
        return shape_task(task)
    if family == "executor":
        return executor_task()
    return TaskConfig(name=task)


def action_bounds(cfg: TaskConfig) -> float:
    """The half-width of the box each task's `step` clips its actions to."""
    family = task_entry(cfg.name).family
    if family == "shape":
        return float(cfg.imitate.action_clip)  # deviations from the reference pose, then scaled
    if family == "executor" and cfg.executor.actuation == "pd":
        return EXECUTOR_PD_ACTION_CLIP  # PD target offsets, then scaled by pd_action_scale
    return 1.0  # reach's motors and the executor's torques: fractions of the force limit


class MorphmimicEnv(gymnasium.Env):
    """One task's environment (`common.tasks.registry.make_env`) behind Gymnasium's API; see
    the module docstring."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, task: str, config: TaskConfig | None = None, render_mode: str | None = None,
                 width: int = 480, height: int = 480):
        cfg = default_config(task) if config is None else config
        if cfg.name != task:
            raise ValueError(f"config is for task {cfg.name!r}, not {task!r} ({env_id(task)})")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode {render_mode!r} is not one of {self.metadata['render_modes']} or None")
        self.task, self.cfg = task, cfg
        self.env = make_env(cfg, 0)
        self.render_mode, self.width, self.height = render_mode, int(width), int(height)
        self.metadata = {**self.metadata, "render_fps": int(round(cfg.control_hz))}
        self.observation_space = spaces.Box(-np.inf, np.inf, (self.env.obs_dim,), np.float32)
        bound = action_bounds(cfg)
        self.action_space = spaces.Box(-bound, bound, (self.env.act_dim,), np.float32)
        self.param_space = self.env.space
        """The task's per-episode parameters (`common.params.ParamSpace`): what `options` sets."""
        self._takes_start = "start_s" in inspect.signature(self.env.reset).parameters
        self._renderer: mujoco.Renderer | None = None
        self._rendered_model: mujoco.MjModel | None = None
        self._seeded = False

    def _episode(self, options: Mapping[str, Any]) -> tuple[np.ndarray, dict[str, Any]]:
        """The parameter vector and the extra reset arguments of `options`."""
        unknown = sorted(set(options) - set(OPTIONS))
        if unknown:
            raise ValueError(f"reset options {unknown} unknown; allowed: {list(OPTIONS)}")
        if "params" in options and "shape" in options:
            raise ValueError("reset options: give 'params' or 'shape', not both")
        given = options.get("params", options.get("shape"))
        if "shape" in options and not isinstance(given, Mapping):
            raise ValueError(f"reset option 'shape' takes a mapping of {list(self.param_space.names)} to values")
        try:
            params = self.param_space.uniform(self.np_random, 1)[0] if given is None else self.param_space.validate(given)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"reset option {'shape' if 'shape' in options else 'params'!r} = {given!r}: {exc}; give "
                             f"{len(self.param_space.names)} numbers in the order {list(self.param_space.names)}") from None
        extra: dict[str, Any] = {}
        if options.get("clip_id") is not None:
            if not isinstance(options["clip_id"], str) or not self._takes_start:
                raise ValueError(f"reset option 'clip_id' = {options['clip_id']!r}: give a clip id (str) of a task that "
                                 f"tracks clips; {self.task} tracks none" if not self._takes_start else
                                 f"reset option 'clip_id' = {options['clip_id']!r}: give a clip id (str)")
            extra["clip_id"] = options["clip_id"]
        if options.get("start_s") is not None:
            if not self._takes_start:
                raise ValueError(f"reset option 'start_s': {self.task} starts where its own rules say")
            try:
                extra["start_s"] = float(options["start_s"])
            except (TypeError, ValueError):
                raise ValueError(f"reset option 'start_s' = {options['start_s']!r}: give seconds into the clip") from None
        return params, extra

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        params, extra = self._episode(options or {})
        # The task's own generator (start phase, initial state, clip draw) follows Gymnasium's.
        inner_seed = int(self.np_random.integers(2**31)) if seed is not None or not self._seeded else None
        self._seeded = True
        obs, info = self.env.reset(inner_seed, params, **extra)
        return obs, dict(info)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(np.asarray(action, dtype=np.float64))
        return obs, float(reward), bool(terminated), bool(truncated), info

    def _camera(self) -> mujoco.MjvCamera:
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        character = getattr(self.env, "character", None)
        if character is None:  # the reach arm: from above
            cam.lookat[:] = (0.0, 0.0, 0.0)
            cam.distance, cam.azimuth, cam.elevation = 0.75, 90.0, -75.0
            return cam
        root = self.env.model.body(character.root_body).id
        cam.lookat[:] = self.env.data.subtree_com[root]
        swimmer = bool(getattr(character, "is_swimmer", False))
        cam.distance, cam.azimuth, cam.elevation = (2.5 if swimmer else 3.0), 120.0, (-30.0 if swimmer else -12.0)
        return cam

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gymnasium.logger.warn("render() without a render_mode: make the env with render_mode='rgb_array'")
            return None
        model = self.env.model
        if self._rendered_model is not model:  # a shape task builds a new model for a new shape
            self.close()
            use_offscreen_context()
            self._renderer = mujoco.Renderer(model, height=self.height, width=self.width)
            self._rendered_model = model
        self._renderer.update_scene(self.env.data, camera=self._camera())
        target = getattr(self.env, "target", None)  # the reach target is no body: drawn as a marker
        scene = self._renderer.scene
        if target is not None and scene.ngeom < scene.maxgeom:
            mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE, np.array([0.012, 0.0, 0.0]),
                                np.array([target[0], target[1], 0.02]), np.eye(3).ravel(),
                                np.array([0.9, 0.2, 0.2, 1.0], np.float32))
            scene.ngeom += 1
        return self._renderer.render().copy()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
        self._renderer, self._rendered_model = None, None


def register_envs() -> list[str]:
    """Register (again) one Gymnasium id per task of `TASKS`; returns the ids."""
    ids = []
    for task in TASKS:
        gymnasium.register(id=env_id(task), entry_point=f"{__name__}:MorphmimicEnv", kwargs={"task": task})
        ids.append(env_id(task))
    return ids


ENV_IDS = register_envs()
