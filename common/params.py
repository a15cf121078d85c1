"""Named, bounded parameter spaces: what a task declares it can vary per episode.

Shapes (Won & Lee 2019, `s_b`) and any other task variable (target speed, steering angle) are
described the same way, so the sampler's MCMC and the marginal value function work on any of
them ("the same machinery applies", METHOD.md A).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np


class ParamError(ValueError):
    """A parameter vector or mapping that does not fit its space; names the value and the range."""


@dataclass(frozen=True)
class ParamSpace:
    """A box of named parameters. `low`, `high`, `default` are tuples in `names` order."""

    names: tuple[str, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]
    default: tuple[float, ...] | None = None
    doc: tuple[str, ...] | None = None
    """One line per parameter: meaning and unit."""

    def __post_init__(self) -> None:
        n = len(self.names)
        if len(set(self.names)) != n:
            raise ParamError(f"parameter names repeat: {list(self.names)}")
        for label, seq in (("low", self.low), ("high", self.high), ("default", self.default or self.low)):
            if len(seq) != n:
                raise ParamError(f"{label} has {len(seq)} entries for {n} parameters {list(self.names)}")
        for name, lo, hi in zip(self.names, self.low, self.high):
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ParamError(f"parameter {name!r}: bounds [{lo}, {hi}] must be finite with low <= high")

    @property
    def dim(self) -> int:
        return len(self.names)

    @property
    def low_array(self) -> np.ndarray:
        return np.asarray(self.low, dtype=np.float64)

    @property
    def high_array(self) -> np.ndarray:
        return np.asarray(self.high, dtype=np.float64)

    @property
    def default_array(self) -> np.ndarray:
        if self.default is None:
            return (self.low_array + self.high_array) / 2
        return np.asarray(self.default, dtype=np.float64)

    def describe(self, i: int) -> str:
        return f"{self.names[i]} in [{self.low[i]:g}, {self.high[i]:g}]"

    def validate(self, values: Sequence[float] | np.ndarray | Mapping[str, float]) -> np.ndarray:
        """Return a float64 vector in `names` order, or raise `ParamError` naming what is wrong.

        A mapping may give a subset of the names; the rest take their defaults.
        """
        if isinstance(values, Mapping):
            unknown = [k for k in values if k not in self.names]
            if unknown:
                raise ParamError(f"unknown parameter(s) {unknown}; allowed: {list(self.names)}")
            vec = self.default_array.copy()
            for k, v in values.items():
                vec[self.names.index(k)] = float(v)
        else:
            vec = np.asarray(values, dtype=np.float64).reshape(-1)
            if vec.shape[0] != self.dim:
                allowed = ", ".join(self.describe(i) for i in range(self.dim))
                raise ParamError(f"expected {self.dim} values for {list(self.names)}, got {vec.shape[0]}: "
                                 f"{vec.tolist()}; allowed: {allowed}")
        for i, v in enumerate(vec):
            if not np.isfinite(v):
                raise ParamError(f"parameter {self.names[i]!r} = {v} is not a finite number; allowed: {self.describe(i)}")
            # NOTE: draws cross the wire as float32, and float32(pi) > pi: a value at a bound may
            # come back a rounding step outside it. Accept that much, then clip into the box.
            tol = 1e-6 * max(1.0, abs(self.low[i]), abs(self.high[i]))  # same rule as validate_batch
            if v < self.low[i] - tol or v > self.high[i] + tol:
                raise ParamError(f"parameter {self.names[i]!r} = {v:g} is out of range; allowed: {self.describe(i)}")
        return np.clip(vec, self.low_array, self.high_array)

    def validate_batch(self, values: np.ndarray) -> np.ndarray:
        """Validate `[n, dim]` rows (clipped into the box as `validate` does); raises on the
        first bad row with its index."""
        arr = np.asarray(values, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] != self.dim:
            raise ParamError(f"expected an [n, {self.dim}] array for {list(self.names)}, got shape {arr.shape}")
        low, high = self.low_array, self.high_array
        tol = 1e-6 * np.maximum(1.0, np.maximum(np.abs(low), np.abs(high)))
        ok = np.isfinite(arr) & (arr >= low - tol) & (arr <= high + tol)
        if not ok.all():
            row = int(np.flatnonzero(~ok.all(axis=1))[0])
            try:
                self.validate(arr[row])
            except ParamError as exc:
                raise ParamError(f"row {row}: {exc}") from None
        return np.clip(arr, low, high)

    def to_dict(self, vec: np.ndarray) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, vec)}

    def uniform(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """`[n, dim]` uniform draws over the box."""
        return rng.uniform(self.low_array, self.high_array, size=(n, self.dim))

    def to_json(self) -> dict:
        return {"names": list(self.names), "low": list(self.low), "high": list(self.high),
                "default": list(self.default_array)}
