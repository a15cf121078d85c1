"""Heavier or lighter bodies in a compiled model: the zero-shot mass tests (UniCon Table 2) and the
live session's mass slider change a model's masses in place rather than recompile it.

MuJoCo derives several fields from the masses when a model is compiled (`mj_setConst`): each
body's subtree mass, by which `data.subtree_com` divides, and the inverse weights and actuator
accelerations that set how soft constraints and contacts are. Writing `body_mass` alone leaves
them at the compiled masses: every centre of mass comes out `factor` times too far from the
origin (at x0.5 the executor's COM term reads 0.03 for a pose that scores 0.66 unscaled), and
the mass rows of the robustness table would measure that error, not the body. `set_body_mass`
writes the masses and recomputes those fields, as a compile with those masses would.
"""

from __future__ import annotations

import mujoco
import numpy as np


def set_body_mass(model: mujoco.MjModel, mass: np.ndarray, inertia: np.ndarray, bodies: slice | np.ndarray = slice(None)) -> None:
    """Set `model.body_mass[bodies]` and `model.body_inertia[bodies]` and recompute what MuJoCo
    derives from them (`mujoco.mj_setConst`, run on scratch data so no simulation state moves)."""
    mass, inertia = np.asarray(mass, float), np.asarray(inertia, float)
    if not (np.all(np.isfinite(mass)) and np.all(mass >= 0) and np.all(np.isfinite(inertia)) and np.all(inertia >= 0)):
        raise ValueError("body masses and inertias must be finite and >= 0")
    model.body_mass[bodies] = mass
    model.body_inertia[bodies] = inertia
    mujoco.mj_setConst(model, mujoco.MjData(model))


def scale_body_mass(model: mujoco.MjModel, base_mass: np.ndarray, base_inertia: np.ndarray, factor: float,
                    bodies: slice | np.ndarray = slice(None)) -> None:
    """Every body in `bodies` `factor` times as heavy as in `base_mass`/`base_inertia` (arrays of
    those bodies), with the derived fields recomputed (`set_body_mass`)."""
    set_body_mass(model, np.asarray(base_mass) * factor, np.asarray(base_inertia) * factor, bodies)
