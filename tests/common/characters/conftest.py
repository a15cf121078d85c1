"""Shared helpers for the character tests."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

REPO = Path(__file__).resolve().parents[3]
FISH_XML = REPO / "common" / "data" / "models" / "dm_control_fish" / "fish.xml"
LEGGED = ["humanoid", "biped", "lower_biped", "quadruped"]
DIVERGENCE = (mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL)


def divergence_count(data: mujoco.MjData) -> int:
    return int(sum(data.warning[w].number for w in DIVERGENCE))


def floor_penetration_m(model: mujoco.MjModel, data: mujoco.MjData) -> float:
    """Deepest contact penetration (m, >= 0) in `data`'s current contacts."""
    mujoco.mj_forward(model, data)
    return max([0.0] + [-float(data.contact.dist[i]) for i in range(data.ncon)])


def foot_vertex_heights(ch, qpos: np.ndarray) -> np.ndarray:
    """World z [m] of the 4 lowest corners of every foot box at `qpos`."""
    from common.characters.pose_solve import foot_points_world, lower_vertices

    data = mujoco.MjData(ch.model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(ch.model, data)
    ids = [ch.model.geom(g).id for g in ch.foot_geoms]
    return foot_points_world(ch.model, data, ids, [lower_vertices(ch.model, data, g) for g in ids])[:, 2]
