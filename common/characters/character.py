"""`Character`: a base character B shaped by parameters b (C = F(B, b)), compiled and posed.

`load_character(preset, shape, parameterization)` is the one way in: it builds B with
MjSpec, validates b, applies the shape operator F (operator.py), compiles, and solves the
standing pose lazily on first use (pose_solve.py). Nothing is returned on error: every bad
input raises one `ShapeError`.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from common.characters.builder import FLOOR_NAME, BaseCharacter
from common.characters.errors import ShapeError
from common.characters.operator import BaseGeometry, apply_scales, unscalable
from common.characters.pose_solve import PoseSolveConfig, foot_points_world, lower_vertices, solve_standing_pose
from common.characters.presets import PRESETS
from common.characters.presets.mjcf import build as build_mjcf
from common.characters.shape_space import ShapeSpace

DEFAULT_TIMESTEP_S = 1.0 / 480.0
"""Physics step [s]. The paper runs 600 Hz; 480 Hz (16 substeps per 30 Hz control step) keeps
every preset stable under random actions at the extremes of its shape box and costs 20% less.
Pass `timestep_s=1/600` for the paper's rate."""
SWIM_HEIGHT_M = 1.0
"""Swimmers start this far above the (untouchable) floor."""


@dataclass(frozen=True)
class Character:
    """A shaped, compiled character. Arrays are float64; lengths in m, masses in kg.

    spec/model: the MjSpec and its compiled MjModel (the spec is owned: `morph` re-shapes it
    in place, after which only the Character `morph` returns is valid).
    shape: the validated values [P] in `space` order. geometry: F's record of the base lengths.
    """

    preset: str
    spec: mujoco.MjSpec
    model: mujoco.MjModel
    base: BaseCharacter
    geometry: BaseGeometry
    space: ShapeSpace
    shape: np.ndarray
    pose_config: PoseSolveConfig = PoseSolveConfig()

    @property
    def parameterization(self) -> str:
        return self.space.name

    @property
    def is_swimmer(self) -> bool:
        return self.base.is_swimmer

    @property
    def joint_names(self) -> list[str]:
        """Actuated (non-free) joints in qpos order after the free root."""
        m = self.model
        return [m.joint(j).name for j in range(m.njnt) if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE]

    @property
    def qpos_slices(self) -> dict[str, slice]:
        """Joint name -> its slice of qpos (4 wide for a ball joint's quaternion (w, x, y, z))."""
        return _slices(self.model, self.model.jnt_qposadr, {0: 7, 1: 4, 2: 1, 3: 1})

    @property
    def dof_slices(self) -> dict[str, slice]:
        """Joint name -> its slice of qvel (3 wide for a ball joint: body-frame angular velocity)."""
        return _slices(self.model, self.model.jnt_dofadr, {0: 6, 1: 3, 2: 1, 3: 1})

    @property
    def actuator_names(self) -> list[str]:
        return [self.model.actuator(i).name for i in range(self.model.nu)]

    @property
    def foot_geoms(self) -> tuple[str, ...]:
        return self.base.foot_geoms

    @property
    def foot_bodies(self) -> tuple[str, ...]:
        return tuple(self.model.body(int(self.model.geom(g).bodyid[0])).name for g in self.base.foot_geoms)

    @property
    def end_effector_bodies(self) -> tuple[str, ...]:
        return self.base.end_effector_bodies

    @property
    def root_body(self) -> str:
        return self.base.root_body

    @property
    def dof(self) -> int:
        """Actuated degrees of freedom: nv minus the 6 of the free root (= model.nu for presets)."""
        return int(self.model.nv - 6)

    @property
    def mass_kg(self) -> float:
        return float(self.model.body_mass.sum())

    @functools.cached_property
    def standing_qpos(self) -> np.ndarray:
        """qpos [nq] standing (METHOD.md A pose solve) or, for swimmers and legless MJCF, the
        rest pose with the lowest point on the floor / the swimmer at SWIM_HEIGHT_M."""
        q0 = self.model.qpos0.copy()
        if self.base.foot_geoms:
            ids = [self.model.geom(g).id for g in self.base.foot_geoms]
            return solve_standing_pose(self.model, q0, ids, self.pose_config)
        if self.is_swimmer:
            return q0
        data = mujoco.MjData(self.model)
        data.qpos[:] = q0
        mujoco.mj_kinematics(self.model, data)
        q0[2] -= extent(self.model, data, 2)[0]
        return q0

    @functools.cached_property
    def height_m(self) -> float:
        """Vertical extent of the geoms in the standing pose (m)."""
        lo, hi = extent(self.model, self.make_data(), 2)
        return float(hi - lo)

    @functools.cached_property
    def length_m(self) -> float:
        """Extent along the world x axis (forward) in the standing pose (m): a swimmer's length."""
        lo, hi = extent(self.model, self.make_data(), 0)
        return float(hi - lo)

    @functools.cached_property
    def leg_lengths_m(self) -> np.ndarray:
        """Per leg (order of `base.legs`): height of the hip joint above the foot's lowest
        vertex at the rest pose (all joints zero, legs hanging straight), [n_legs] m."""
        data = mujoco.MjData(self.model)
        mujoco.mj_kinematics(self.model, data)
        out = []
        for hip, foot in self.base.legs:
            b = self.model.body(hip).id
            hip_z = data.xanchor[self.model.body_jntadr[b]][2]
            g = self.model.geom(foot).id
            pts = foot_points_world(self.model, data, [g], [lower_vertices(self.model, data, g)])
            out.append(hip_z - pts[:, 2].min())
        return np.array(out)

    def make_data(self) -> mujoco.MjData:
        """A fresh MjData at the standing pose, zero velocity, mj_forward done."""
        data = mujoco.MjData(self.model)
        data.qpos[:] = self.standing_qpos
        mujoco.mj_forward(self.model, data)
        return data

    def summary(self) -> str:
        legs = ", ".join(f"{x:.3f}" for x in self.leg_lengths_m) or "-"
        return (f"{self.preset} ({self.parameterization}): mass {self.mass_kg:.2f} kg, height {self.height_m:.3f} m, "
                f"length {self.length_m:.3f} m, leg lengths [{legs}] m, dof {self.dof} (nq {self.model.nq}, "
                f"nv {self.model.nv}, nu {self.model.nu}, bodies {self.model.nbody - 1})")


def extent(model: mujoco.MjModel, data: mujoco.MjData, axis: int, bodies: np.ndarray | None = None) -> tuple[float, float]:
    """(min, max) world coordinate along `axis` over the geoms of `bodies` (default: every body
    but the world, so the floor is excluded)."""
    keep = model.geom_bodyid != 0 if bodies is None else np.isin(model.geom_bodyid, bodies)
    rot = data.geom_xmat[keep].reshape(-1, 3, 3)[:, axis, :]
    centre = data.geom_xpos[keep][:, axis] + np.einsum("gj,gj->g", rot, model.geom_aabb[keep, :3])
    half = np.einsum("gj,gj->g", np.abs(rot), model.geom_aabb[keep, 3:])
    return float(np.min(centre - half)), float(np.max(centre + half))


def _slices(model, adr, width) -> dict[str, slice]:
    out = {}
    for j in range(model.njnt):
        if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE:
            a = int(adr[j])
            out[model.joint(j).name] = slice(a, a + width[int(model.jnt_type[j])])
    return out


def list_presets() -> list[str]:
    """Preset names for `load_character`; a user file is passed as "mjcf:/path/to/file.xml"."""
    return list(PRESETS)


def build_base(preset: str, timestep_s: float = DEFAULT_TIMESTEP_S) -> BaseCharacter:
    """The unshaped base character B for a preset name or "mjcf:<path>" / "<path>.xml" / the path
    of any existing file (MuJoCo decides whether it is MJCF)."""
    if preset.startswith("mjcf:") or preset.endswith(".xml") or (preset not in PRESETS and Path(preset).exists()):
        return build_mjcf(preset.removeprefix("mjcf:"), timestep_s)
    if preset not in PRESETS:
        raise ShapeError(f"unknown character preset {preset!r}; choose one of {', '.join(PRESETS)} "
                         "or pass a user file as 'mjcf:/path/to/file.xml'")
    return PRESETS[preset](timestep_s)


def load_character(
    preset: str,
    shape: Mapping[str, float] | Sequence[float] | np.ndarray | None = None,
    parameterization: str = "random",
    timestep_s: float | None = None,
    pose_config: PoseSolveConfig = PoseSolveConfig(),
) -> Character:
    """Build C = F(B, b): preset (see `list_presets`) or "mjcf:<path>", shape values (a dict
    name -> value naming any subset, a full vector, or None for the base), the name of one of
    the preset's parameterizations (`Character.base.spaces`). timestep_s: physics step [s]
    (DEFAULT_TIMESTEP_S for presets; a user MJCF keeps its own unless given).
    Raises ShapeError on any bad input."""
    return CharacterFactory(preset, parameterization, timestep_s, pose_config).make(shape)


class CharacterFactory:
    """Many shapes of one preset and parameterization, built from one base.

    `load_character` builds the base character B (MjSpec), compiles it and captures its
    geometry for every call; for a stream of shapes (an environment draws one per episode) that
    was 11 of its 14.5 ms on the lower-body biped. A factory does it once, and `make` only
    re-shapes the base spec (`reshape` writes absolute values, so each call is a clean re-shape)
    and compiles it: the models are identical to `load_character`'s.

    NOTE: every Character a factory makes shares its spec: a Character's `model` stays valid,
    but its `spec` describes the latest shape made (or morphed). Use `load_character` for a
    Character that owns its spec.
    """

    def __init__(self, preset: str, parameterization: str = "random", timestep_s: float | None = None,
                 pose_config: PoseSolveConfig = PoseSolveConfig()):
        if timestep_s is not None and not (np.isfinite(timestep_s) and 0 < timestep_s <= 0.05):
            raise ShapeError(f"timestep_s = {timestep_s} is outside (0, 0.05] s")
        base = build_base(preset, timestep_s if timestep_s is not None else DEFAULT_TIMESTEP_S)
        if timestep_s is not None:
            base.spec.option.timestep = timestep_s
        if parameterization not in base.spaces:
            raise ShapeError(f"unknown parameterization {parameterization!r} for {base.preset!r}; "
                             f"choose one of {', '.join(base.spaces)}")
        self.base = base
        self.space = base.spaces[parameterization]
        self.pose_config = pose_config
        self.geometry = BaseGeometry.capture(base.spec, _compile(base.spec, base.preset))

    def make(self, shape: Mapping[str, float] | Sequence[float] | np.ndarray | None = None) -> Character:
        """C = F(B, b) for shape values b (as in `load_character`); raises ShapeError on bad values."""
        values = self.space.validate(shape)
        reshape(self.base.spec, self.base, self.geometry, self.space, values)
        model = _compile(self.base.spec, self.base.preset)
        return Character(self.base.preset, self.base.spec, model, self.base, self.geometry, self.space, values,
                         self.pose_config)


def reshape(spec: mujoco.MjSpec, base: BaseCharacter, geometry: BaseGeometry, space: ShapeSpace,
            values: np.ndarray) -> None:
    """Apply F for validated `values` to `spec` in place (no compile). Raises ShapeError, before
    changing anything, if the values would scale a body whose geoms F cannot rescale."""
    scales = space.segment_scales(values, base.parts, geometry.rest_rot)
    fixed = unscalable(geometry, scales)
    if fixed is not None:
        raise ShapeError(f"{base.preset!r}: body {fixed[0]!r} carries a {fixed[1]} geom, which the shape operator "
                         "cannot rescale; choose shape values that leave that body at scale 1")
    long_axis = {p.name: p.long_axis for p in base.parts}
    apply_scales(spec, geometry, scales, geometry.torque_scale(scales, long_axis))


def _compile(spec: mujoco.MjSpec, name: str) -> mujoco.MjModel:
    try:
        return spec.compile()
    except Exception as exc:  # MuJoCo raises a plain ValueError with its compiler message
        raise ShapeError(f"character {name!r} does not compile: {' '.join(str(exc).split())}") from exc


__all__ = ["Character", "CharacterFactory", "load_character", "list_presets", "build_base", "reshape", "FLOOR_NAME", "DEFAULT_TIMESTEP_S"]


@functools.lru_cache(maxsize=None)
def base_character(preset: str, timestep_s: float = DEFAULT_TIMESTEP_S) -> Character:
    """The preset at its default shape, built once per process and (preset, timestep): the body
    that clips are prepared on and the shape spaces are read from. Treat it as read-only."""
    return load_character(preset, timestep_s=timestep_s)
