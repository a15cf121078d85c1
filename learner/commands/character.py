"""`morphmimic character`: build a character from a preset (or MJCF file) and shape values,
print its mass, height, leg lengths and DOF count, write its MJCF and a PNG of it standing.

    morphmimic character lower_biped --parameterization left_right_leg --shape left_leg=1.1 --png lb.png
    morphmimic character humanoid --list
    morphmimic character path/to/file.xml --shape scale=1.3 --parameterization uniform --mjcf out.xml

Rendering needs an offscreen OpenGL on a machine without a display: MUJOCO_GL=egl (or osmesa);
this command picks the one installed when MUJOCO_GL is unset and there is no DISPLAY.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import tyro

from common.characters import ShapeError, list_presets, load_character
from common.characters.character import build_base
from common.config_limits import Limit, above, check_limits, validated
from learner.cli_options import parse_options


@validated
@dataclass
class CharacterOptions:
    preset: tyro.conf.Positional[str]
    """A character preset (see the list above), or an MJCF file (mjcf:path or *.xml)."""
    shape: str | None = None
    """Comma-separated name=value shape parameters (see --list)."""
    parameterization: str = "random"
    """Named parameterization of the preset (see --list)."""
    timestep: float | None = None
    """Physics step in seconds (default 1/480)."""
    mjcf: str | None = None
    """Write the shaped character as MJCF to this path."""
    png: str | None = None
    """Render the standing character to this PNG."""
    list: bool = False
    """List the parameterizations and their parameters, then exit."""

    LIMITS: ClassVar[dict[str, Limit]] = {"timestep": above(0)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def _parse_shape(text: str | None) -> dict[str, str]:
    if not text:
        return {}
    out = {}
    for item in text.split(","):
        if "=" not in item:
            raise ValueError(f"--shape item {item!r} is not name=value")
        key, value = item.split("=", 1)
        out[key.strip()] = value.strip()
    return out


def main(argv: list[str]) -> int:
    description = f"{__doc__.split(chr(10) * 2)[0]}\n\npresets: {', '.join(list_presets())}"
    args = parse_options(CharacterOptions, argv,
                         prog="morphmimic character", description=description)
    try:
        if args.list:
            base = build_base(args.preset)
            for space in base.spaces.values():
                print(f"{space.name}: {space.doc}")
                for p in space.params:
                    print(f"    {p.name:<24} [{p.low:g}, {p.high:g}]  {p.doc}")
            return 0
        ch = load_character(args.preset, _parse_shape(args.shape), args.parameterization, timestep_s=args.timestep)
        print(ch.summary())
        print(f"mass_kg {ch.mass_kg:.3f}")
        print(f"height_m {ch.height_m:.4f}")
        print("leg_lengths_m " + (" ".join(f"{x:.4f}" for x in ch.leg_lengths_m) or "-"))
        print(f"dof {ch.dof}")
        if args.mjcf:
            name = "" if any(k.name == "stand" for k in ch.spec.keys) else "stand"  # a user file may have one
            key = ch.spec.add_key(name=name, qpos=list(ch.standing_qpos))
            try:
                ch.spec.compile()
                Path(args.mjcf).parent.mkdir(parents=True, exist_ok=True)
                with open(args.mjcf, "w") as f:
                    f.write(ch.spec.to_xml())
            finally:
                ch.spec.delete(key)
            print(f"wrote {args.mjcf}")
        if args.png:
            from common.characters.render import render_png  # lazy: heavy (imageio), only with --png

            Path(args.png).parent.mkdir(parents=True, exist_ok=True)
            render_png(ch, args.png)
            print(f"wrote {args.png}")
    except (ShapeError, ValueError) as exc:
        print(f"morphmimic character: {exc}", file=sys.stderr)
        return 2
    return 0
