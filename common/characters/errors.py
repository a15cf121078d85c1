"""The one error a caller of `common.characters` has to handle."""

from __future__ import annotations


class ShapeError(ValueError):
    """A character could not be built from the given preset, file or shape values.

    Raised for unknown parameter names, values out of range or not finite, a shape vector of
    the wrong length, an unknown preset or parameterization, an MJCF file that does not parse
    or whose root body has no free joint. The message names the offending value, what was
    allowed, and what to do next. Nothing half-built is ever returned alongside it.
    """
