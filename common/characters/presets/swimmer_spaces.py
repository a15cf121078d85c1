"""Parameterizations shared by the swimmers (fish, manta ray, swimming MJCF files)."""

from __future__ import annotations

from common.characters.shape_space import ShapeParam, ShapeSpace


def swimmer_spaces(wing_groups: tuple[str, ...] | None) -> list[ShapeSpace]:
    """Body length vs thickness; with `wing_groups`, also wing span vs tail length."""
    spaces = [ShapeSpace("length_thickness", (
        ShapeParam("length", 0.75, 1.5, ("*",), "long", "length of every segment along its long axis"),
        ShapeParam("thickness", 0.5, 1.5, ("*",), "thick", "cross-section of every segment"),
    ), "body length x0.75..x1.5 vs thickness x0.5..x1.5")]
    if wing_groups is not None:
        spaces.append(ShapeSpace("wing_tail", (
            ShapeParam("wing_span", 0.5, 1.5, wing_groups, "long", "span of each wing segment"),
            ShapeParam("tail_length", 0.5, 2.0, ("tail",), "long", "length of the tail"),
        ), "wing span x0.5..x1.5 vs tail length x0.5..x2.0"))
    return spaces
