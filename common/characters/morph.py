"""Shape change during simulation (Won & Lee 2019, section 3; METHOD.md A "on the fly").

The character's spec is re-shaped in place by F and recompiled with `MjSpec.recompile(model,
data)`, which returns a new MjData carrying the state (qpos, qvel, act, ctrl, time) across.
If a limb grew into the floor, the root is lifted by the deepest penetration.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

import mujoco
import numpy as np

from common.characters.character import Character, reshape
from common.characters.errors import ShapeError

LIFT_MARGIN_M = 1e-4
"""Extra clearance [m] after a lift, so the first contact is not a fresh penetration."""


def morph(ch: Character, new_shape: Mapping[str, float] | Sequence[float] | np.ndarray,
          data: mujoco.MjData) -> tuple[Character, mujoco.MjData]:
    """Change `ch` to `new_shape` (same parameterization) keeping the state of `data`.

    Returns the new Character and a new MjData (mj_forward done). `ch` and `data` must not be
    used afterwards: the spec is shared and re-shaped in place (cheaper than a copy).
    Raises ShapeError on a bad shape, before anything is changed.
    """
    values = ch.space.validate(new_shape)
    reshape(ch.spec, ch.base, ch.geometry, ch.space, values)
    try:
        new_model, new_data = ch.spec.recompile(ch.model, data)
    except Exception as exc:
        raise ShapeError(f"re-shaped {ch.preset!r} does not compile: {exc}") from exc
    if not ch.is_swimmer:
        lift_out_of_floor(new_model, new_data)
    else:
        mujoco.mj_forward(new_model, new_data)
    return replace(ch, model=new_model, shape=values), new_data


def lift_out_of_floor(model: mujoco.MjModel, data: mujoco.MjData) -> float:
    """Raise the free root by the deepest floor penetration (m, returned; 0 if none)."""
    mujoco.mj_forward(model, data)
    depth = 0.0
    for i in range(data.ncon):
        depth = max(depth, -float(data.contact.dist[i]))
    if depth > 0.0:
        data.qpos[2] += depth + LIFT_MARGIN_M
        mujoco.mj_forward(model, data)
    return depth
