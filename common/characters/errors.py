"""The one error a caller of `common.characters` has to handle."""

from __future__ import annotations


class ShapeError(ValueError):
    """A character could not be built from the given preset, file or shape values.

    Raised for unknown parameter names, values out of range or not finite, a shape vector of
    the wrong length, an unknown preset or parameterization, an MJCF file that MuJoCo does not
    load or compile or that has no free-jointed root body (on one line naming the file), shape
    values that would rescale a mesh. The message names the offending value, what was allowed,
    and what to do next. Nothing half-built is ever returned alongside it.
    """
