"""Named, bounded shape parameters and the parameterizations built from them.

A *parameterization* is a `ShapeSpace`: an ordered tuple of `ShapeParam`, each a scalar factor
with a range, a default of 1.0 (the base character) and a list of body parts it stretches.
`ShapeSpace.segment_scales` turns a value vector into one 3-D scale per body, which the shape
operator `F` (operator.py) applies: `C = F(B, b)` of Won & Lee 2019, section 3 / METHOD.md A.

Axes a parameter can stretch (see `AXES`):
- "long": the body's long axis (the bone direction, declared per body by the preset);
- "thick": the two other body axes (cross-section);
- "all", "x", "y", "z": body-frame axes;
- "wx", "wy", "wz": world axes at the rest pose (MuJoCo Z up, X forward): the paper's global
  scale `b_g`; they are mapped into each body's frame through its rest orientation.
Factors from several parameters on the same axis multiply.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from common.characters.errors import ShapeError

AXES = ("long", "thick", "all", "x", "y", "z", "wx", "wy", "wz")


@dataclass(frozen=True)
class BodyPart:
    """Shape metadata of one body: which groups it belongs to and its long (bone) axis.

    name: MuJoCo body name. groups: tags a parameter may target ("leg", "leg_left", "arm",
    "upper", "lower", ...). long_axis: 0, 1 or 2, the body-frame axis along the bone.
    """

    name: str
    groups: tuple[str, ...] = ()
    long_axis: int = 2


@dataclass(frozen=True)
class ShapeParam:
    """One named scalar shape factor (dimensionless, 1.0 = base character).

    targets: body names or group tags it stretches; "*" means every body.
    axes: one of `AXES`. doc: what it means, shown by `morphmimic character --list`.
    """

    name: str
    low: float
    high: float
    targets: tuple[str, ...]
    axes: str
    doc: str = ""
    default: float = 1.0

    def __post_init__(self) -> None:
        if self.axes not in AXES:
            raise ValueError(f"ShapeParam {self.name}: axes {self.axes!r} not in {AXES}")
        if not self.low <= self.default <= self.high:
            raise ValueError(f"ShapeParam {self.name}: default {self.default} outside [{self.low}, {self.high}]")


@dataclass(frozen=True)
class ShapeSpace:
    """An ordered box of named shape parameters: one parameterization of one character.

    `names`, `low`, `high`, `default` are in parameter order (arrays of shape [P]).
    """

    name: str
    params: tuple[ShapeParam, ...]
    doc: str = ""
    _index: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_index", {p.name: i for i, p in enumerate(self.params)})

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.params]

    @property
    def low(self) -> np.ndarray:
        return np.array([p.low for p in self.params], dtype=np.float64)

    @property
    def high(self) -> np.ndarray:
        return np.array([p.high for p in self.params], dtype=np.float64)

    @property
    def default(self) -> np.ndarray:
        return np.array([p.default for p in self.params], dtype=np.float64)

    def __len__(self) -> int:
        return len(self.params)

    def validate(self, shape: Mapping[str, float] | Sequence[float] | np.ndarray | None) -> np.ndarray:
        """Check shape values and return them as a [P] float64 vector in parameter order.

        A mapping may name any subset of parameters (the rest keep their default); a
        sequence/array must give all P values. None means the base character.
        Raises ShapeError naming the parameter, the value and the allowed range.
        """
        if shape is None:
            return self.default
        if isinstance(shape, Mapping):
            values = self.default
            for key, raw in shape.items():
                if key not in self._index:
                    raise ShapeError(
                        f"unknown shape parameter {key!r} for parameterization {self.name!r}; "
                        f"allowed: {', '.join(self.names)} (see `morphmimic character <preset> --list`)"
                    )
                values[self._index[key]] = self._check(key, raw, self.params[self._index[key]])
            return values
        try:
            arr = np.asarray(shape, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ShapeError(f"shape for {self.name!r} must be a dict name->value or {len(self)} numbers; got {shape!r}") from exc
        if arr.ndim != 1 or arr.shape[0] != len(self):
            raise ShapeError(
                f"shape vector for parameterization {self.name!r} has shape {arr.shape}, expected ({len(self)},) "
                f"in the order {', '.join(self.names)}"
            )
        return np.array([self._check(p.name, v, p) for p, v in zip(self.params, arr)], dtype=np.float64)

    @staticmethod
    def _check(name: str, raw: object, p: ShapeParam) -> float:
        try:
            value = float(raw)  # type: ignore[arg-type]
        except (TypeError, ValueError) as exc:
            raise ShapeError(f"shape parameter {name!r} = {raw!r} is not a number; allowed range [{p.low}, {p.high}]") from exc
        if not np.isfinite(value) or not p.low <= value <= p.high:
            raise ShapeError(f"shape parameter {name!r} = {value} is outside the allowed range [{p.low}, {p.high}]")
        return value

    def to_dict(self, values: np.ndarray) -> dict[str, float]:
        """Vector [P] -> {name: value}."""
        values = self.validate(values)
        return {n: float(v) for n, v in zip(self.names, values)}

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """A uniform draw from the box, shape [P]."""
        return rng.uniform(self.low, self.high)

    def segment_scales(
        self, values: np.ndarray, parts: Sequence[BodyPart], rest_rot: Mapping[str, np.ndarray]
    ) -> dict[str, np.ndarray]:
        """Per-body 3-D scale factors (body frame, dimensionless) for validated `values` [P].

        rest_rot: body name -> [3, 3] rotation body->world at the rest pose, used to map the
        world-axis factors ("wx", "wy", "wz") of the global scale b_g into the body frame:
        the factor along body axis a is ||diag(f_world) R[:, a]||.
        """
        world = {p.name: np.ones(3) for p in parts}
        local = {p.name: np.ones(3) for p in parts}
        for param, value in zip(self.params, values):
            for part in parts:
                if not _targets(param, part):
                    continue
                if param.axes.startswith("w"):
                    world[part.name]["xyz".index(param.axes[1])] *= value
                else:
                    local[part.name][_axis_mask(param.axes, part.long_axis)] *= value
        scales = {}
        for part in parts:
            rot = rest_rot[part.name]
            scales[part.name] = np.linalg.norm(world[part.name][:, None] * rot, axis=0) * local[part.name]
        return scales


def _targets(param: ShapeParam, part: BodyPart) -> bool:
    return "*" in param.targets or part.name in param.targets or any(g in param.targets for g in part.groups)


def _axis_mask(axes: str, long_axis: int) -> np.ndarray:
    mask = np.zeros(3, dtype=bool)
    if axes == "long":
        mask[long_axis] = True
    elif axes == "thick":
        mask[:] = True
        mask[long_axis] = False
    elif axes == "all":
        mask[:] = True
    else:
        mask["xyz".index(axes)] = True
    return mask


def random_space(parts: Sequence[BodyPart], global_range=(0.5, 1.5), local_range=(0.7, 1.2)) -> ShapeSpace:
    """Won & Lee 2019 random characters: global b_g in [0.5,1.5]^3 (world axes) and per-segment
    b_l in [0.7,1.2]^3 (body axes), parameters `global_x|y|z` and `<body>_x|y|z`."""
    params = [
        ShapeParam(f"global_{a}", *global_range, ("*",), f"w{a}", f"global scale along world {a} (b_g)") for a in "xyz"
    ]
    for part in parts:
        params += [
            ShapeParam(f"{part.name}_{a}", *local_range, (part.name,), a, f"scale of body {part.name} along its {a} axis (b_l)")
            for a in "xyz"
        ]
    return ShapeSpace("random", tuple(params), "global 3-D scale b_g in [0.5,1.5]^3 times per-segment b_l in [0.7,1.2]^3")


def uniform_space() -> ShapeSpace:
    """One factor scaling every length; mass then scales with its cube."""
    return ShapeSpace("uniform", (ShapeParam("scale", 0.5, 1.5, ("*",), "all", "uniform scale of every length"),), "uniform scale")
