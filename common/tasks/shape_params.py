"""A character's shape parameters as a task's per-episode parameters (Won & Lee 2019's s_b,
METHOD.md A), one rule for every task that simulates a shaped body (the shape tasks, the
executor): the parameterization's box, shrunk toward the base shape by `shape_box_scale`, or
pinned to the base shape when the shape does not vary."""

from __future__ import annotations

import numpy as np

from common.characters import base_character
from common.params import ParamSpace
from common.tasks.body_config import BodyConfig


def shape_param_space(preset: str, body: BodyConfig, timestep_s: float) -> ParamSpace:
    """The shape parameters of `body.parameterization` of character `preset` (built at
    `timestep_s`): its box with `body.vary_shape` (each bound moved to base + shape_box_scale x
    (bound - base)), else low = high = the base shape. ValueError naming an unknown
    parameterization and the preset's own."""
    spaces = base_character(preset, timestep_s).base.spaces
    shape = spaces.get(body.parameterization)
    if shape is None:
        raise ValueError(f"parameterization {body.parameterization!r} is not one of {sorted(spaces)}")
    d, low, high = shape.default, shape.low, shape.high
    if not body.vary_shape:
        low, high = d, d
    elif body.shape_box_scale != 1.0:
        k = body.shape_box_scale
        low, high = d + k * (low - d), d + k * (high - d)
    default = np.minimum(np.maximum(d, low), high)
    return ParamSpace(tuple(shape.names), tuple(float(x) for x in low), tuple(float(x) for x in high),
                      tuple(float(x) for x in default), tuple(p.doc for p in shape.params))
