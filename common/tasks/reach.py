"""`reach`: a two-link planar arm, built with MjSpec, must put its fingertip on a target.

The toy task that proves the backbone learns before the character tasks exist. The target's
polar position is the per-episode task parameter, drawn by the sampler service, so the same
adaptive-sampling machinery that varies body shapes varies it (METHOD.md A, "the same
machinery applies to any task parameter").

Reward per control step: `exp(-d / 0.03)` with `d` the fingertip-target distance in metres
(a bell, as every term of Won & Lee 2019), minus a small effort cost. A random policy earns
about 0.05 per step; a policy that reaches and holds earns above 0.7.

The target is drawn too (a red ball on a mocap body, outside the physics: not in the arm's tree,
no contact), so a rendered episode (`morphmimic play`, the studio) shows what the arm reaches
for; `view_distance_m` and `view_elevation_deg` tell a viewer's camera where to stand for a
24 cm arm lying in the plane.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from common.params import ParamSpace
from common.tasks.base import TaskConfig, diverged_step, step_physics
from common.tasks.content_bounds import ContentBounds

LINK_M = (0.12, 0.12)
"""Link lengths in metres; the reach radius is their sum."""
GEAR_NM = 0.05
REWARD_SCALE_M = 0.03
EFFORT_COST = 0.01
OBS_MAX_ABS = 1e3
"""Observations are cosines, sines, positions within 0.24 m and 0.1 x joint speed; the 0.05 N m
motors against the joints' damping hold the speed to tens of rad/s (3.2 at most under a random
policy), so 1000 is beyond any honest state."""
ARM_RGBA = (0.47, 0.55, 0.69, 1.0)
"""The characters' blue-grey (`common.characters.builder.BODY_RGBA`), which the studio's
screenshot looks for."""
TARGET_RGBA = (0.85, 0.2, 0.15, 1.0)
TARGET_RADIUS_M = 0.012
VIEW_DISTANCE_M = 0.75
VIEW_ELEVATION_DEG = 55.0


def build_arm() -> mujoco.MjModel:
    spec = mujoco.MjSpec()
    spec.modelname = "reach_arm"
    spec.option.gravity = [0, 0, 0]
    spec.option.timestep = 0.002
    world = spec.worldbody
    world.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.4, 0.4, 0.01], rgba=[0.9, 0.9, 0.9, 1],
                   contype=0, conaffinity=0)
    parent, x = world, 0.0
    for i, length in enumerate(LINK_M):
        body = parent.add_body(name=f"link{i}", pos=[x, 0, 0.02])
        body.add_joint(name=f"joint{i}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1], damping=0.002)
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, 0, length, 0, 0], size=[0.01, 0, 0],
                      density=500, contype=0, conaffinity=0, rgba=list(ARM_RGBA))
        parent, x = body, length
    parent.add_site(name="fingertip", pos=[LINK_M[-1], 0, 0], size=[0.01, 0, 0])
    target = world.add_body(name="target", mocap=True, pos=[0, 0, 0.02])
    target.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[TARGET_RADIUS_M, 0, 0], rgba=list(TARGET_RGBA),
                    contype=0, conaffinity=0)
    for i in range(len(LINK_M)):
        spec.add_actuator(name=f"motor{i}", target=f"joint{i}", trntype=mujoco.mjtTrn.mjTRN_JOINT,
                          gear=[GEAR_NM, 0, 0, 0, 0, 0], ctrlrange=[-1, 1], ctrllimited=1)
    return spec.compile()


class ReachEnv:
    """Gymnasium-style environment; see `common.tasks.base.Env`."""

    obs_dim = 12
    act_dim = 2
    n_shape = 0
    """Leading entries of the parameter vector that are body shape: none (both are the target's)."""
    view_distance_m = VIEW_DISTANCE_M
    view_elevation_deg = VIEW_ELEVATION_DEG

    @staticmethod
    def param_space(cfg: TaskConfig) -> ParamSpace:
        reach = sum(LINK_M)
        return ParamSpace(
            names=("target_angle", "target_radius"),
            low=(-math.pi, 0.2 * reach),
            high=(math.pi, 0.9 * reach),
            doc=("polar angle of the target around the shoulder, rad", "distance of the target from the shoulder, m"),
        )

    @staticmethod
    def clips(cfg: TaskConfig) -> list[tuple[str, str]]:
        return []

    @staticmethod
    def content_bounds(cfg: TaskConfig) -> ContentBounds:
        """A step earns a bell in (0, 1] minus the effort cost of controls clipped to [-1, 1]."""
        return ContentBounds(reward_min=-EFFORT_COST * ReachEnv.act_dim, reward_max=1.0, obs_max_abs=OBS_MAX_ABS,
                             episode_steps=cfg.episode_steps)

    def __init__(self, cfg: TaskConfig, seed: int = 0):
        self.cfg = cfg
        self.space = self.param_space(cfg)
        self.model = build_arm()
        self.model.opt.timestep = 1.0 / cfg.sim_hz
        self.data = mujoco.MjData(self.model)
        self.substeps = cfg.substeps
        self.dt = 1.0 / cfg.control_hz
        """Simulated seconds per control step."""
        self.rng = np.random.default_rng(seed)
        self.target = np.zeros(2)
        self.t = 0
        self.tip = self.model.site("fingertip").id

    def _obs(self) -> np.ndarray:
        q, qd = self.data.qpos, self.data.qvel
        tip = self.data.site_xpos[self.tip][:2]
        return np.concatenate([np.cos(q), np.sin(q), 0.1 * qd, tip, self.target, tip - self.target]).astype(np.float32)

    def reset(self, seed: int | None, params: np.ndarray, clip_id: str | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        angle, radius = self.space.validate(params)
        self.target = radius * np.array([math.cos(angle), math.sin(angle)])
        mujoco.mj_resetData(self.model, self.data)
        self.data.mocap_pos[0, :2] = self.target
        self.data.qpos[:] = self.rng.uniform(-math.pi, math.pi, size=2)
        self.data.qvel[:] = self.rng.normal(0, 0.1, size=2)
        mujoco.mj_forward(self.model, self.data)
        self.t = 0
        return self._obs(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        ctrl = np.clip(action, -1.0, 1.0)
        self.data.ctrl[:] = ctrl
        diverged = step_physics(self.model, self.data, self.substeps)
        self.t += 1
        if diverged:
            return diverged_step(self.obs_dim)
        obs = self._obs()
        dist = float(np.linalg.norm(obs[6:8] - self.target))
        reward = math.exp(-dist / REWARD_SCALE_M) - EFFORT_COST * float(np.square(ctrl).sum())
        truncated = self.t >= self.cfg.episode_steps
        return obs, reward, False, truncated, {"diverged": False, "distance_m": dist}
