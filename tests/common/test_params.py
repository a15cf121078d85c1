"""Parameter spaces: bounds survive a float32 round trip; bad values are named with their range."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.params import ParamError, ParamSpace

SPACE = ParamSpace(("angle", "radius"), (-math.pi, 0.05), (math.pi, 0.2))


def test_float32_bounds_are_accepted_and_clipped():
    at_bounds = np.array([[-math.pi, 0.05], [math.pi, 0.2]], dtype=np.float32)
    assert float(np.float32(math.pi)) > math.pi  # why the tolerance exists
    out = SPACE.validate_batch(at_bounds)
    assert out[1, 0] == math.pi and out[0, 0] == -math.pi
    assert SPACE.validate(at_bounds[1])[0] == math.pi


@pytest.mark.parametrize("values, match", [
    ({"radius": 0.5}, "'radius' = 0.5 is out of range; allowed: radius in \\[0.05, 0.2\\]"),
    ({"size": 1.0}, "unknown parameter"),
    ([0.0], "expected 2 values"),
    ([float("nan"), 0.1], "'angle' = nan is not a finite number"),
])
def test_bad_values_are_named(values, match):
    with pytest.raises(ParamError, match=match):
        SPACE.validate(values)


def test_batch_error_names_the_row():
    with pytest.raises(ParamError, match="row 1: parameter 'radius' = 0.3"):
        SPACE.validate_batch(np.array([[0.0, 0.1], [0.0, 0.3]]))
