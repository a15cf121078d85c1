"""The fitted stroke-speed model of a swimmer: how fast each shape's tracked stroke carries it,
over its length-scaled target (Won & Lee 2019's velocity normalization, METHOD.md A, with a
per-shape correction for fluid; a deviation from the paper, stated wherever figures are compared):

    log(speed / length-scaled target) = b + w . log(shape parameters)

`learner.tools.stroke_fit` measures and fits it; the shape task loads it (`StrokeModel.load`)
when `--task.imitate.swimmer-speed stroke_fit`.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MODEL_DIR = Path(__file__).resolve().parents[2] / "data" / "stroke_speed"
"""Where the fitted models are shipped (`morphmimic stroke-fit` writes them)."""


class StrokeModelError(ValueError):
    """A stroke-speed model file that is missing, malformed or for another shape space."""


def _number(value, what: str, path: Path) -> float:
    """A finite JSON number (not a string or a boolean), else StrokeModelError naming it."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise StrokeModelError(f"stroke-speed model {path}: {what} = {value!r} must be a number")
    try:
        x = float(value)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        raise StrokeModelError(f"stroke-speed model {path}: {what} = {value!r} must be finite")
    return x


@dataclass(frozen=True)
class StrokeModel:
    """`ratio(shape) = exp(bias + weights . log(shape))`, held within `clamp` (the ratios seen
    while fitting): the speed a shape's tracked stroke reaches over its length-scaled target
    (see the module docstring). `digest`: the model file's SHA-256 (first 12 hex digits), which
    evaluations record."""

    preset: str
    names: tuple[str, ...]
    bias: float
    weights: np.ndarray  # [len(names)]
    clamp: tuple[float, float]
    digest: str = ""

    def ratio(self, shape: np.ndarray) -> float:
        x = np.log(np.asarray(shape, dtype=np.float64))
        log_ratio = float(np.clip(self.bias + self.weights @ x, math.log(self.clamp[0]), math.log(self.clamp[1])))
        return math.exp(log_ratio)

    @staticmethod
    def load(preset: str, names: tuple[str, ...], path: Path | None = None) -> StrokeModel:
        """The model of `preset` over the shape parameters `names`; StrokeModelError naming the
        file, the value and what is allowed if it is missing, malformed or fitted on other parameters."""
        path = Path(path or MODEL_DIR / f"{preset}.json")
        try:
            raw = path.read_bytes()
            doc = json.loads(raw)
        except FileNotFoundError:
            raise StrokeModelError(f"stroke-speed model {path} not found: make it with "
                                   f"`morphmimic stroke-fit {preset}`") from None
        except (OSError, ValueError, RecursionError) as e:
            raise StrokeModelError(f"stroke-speed model {path}: not readable JSON ({type(e).__name__}: {e})") from None
        if not isinstance(doc, dict) or not all(k in doc for k in ("preset", "names", "bias", "weights", "clamp")):
            raise StrokeModelError(f"stroke-speed model {path}: needs an object with preset, names, bias, weights and clamp")
        got_names = doc["names"]
        if doc["preset"] != preset or not isinstance(got_names, list) or tuple(got_names) != tuple(names):
            n = len(got_names) if isinstance(got_names, list) else got_names
            raise StrokeModelError(f"stroke-speed model {path} is for {doc['preset']!r} over {n} parameters; "
                                   f"the task needs {preset!r} over {list(names)}")
        if not isinstance(doc["weights"], list) or len(doc["weights"]) != len(names):
            n = len(doc["weights"]) if isinstance(doc["weights"], list) else repr(doc["weights"])
            raise StrokeModelError(f"stroke-speed model {path}: weights has {n} entries; give a list of "
                                   f"{len(names)} numbers, one per parameter")
        if not isinstance(doc["clamp"], list) or len(doc["clamp"]) != 2:
            raise StrokeModelError(f"stroke-speed model {path}: clamp = {doc['clamp']!r} must be [low, high]")
        bias = _number(doc["bias"], "bias", path)
        weights = np.array([_number(w, f"weights[{i}]", path) for i, w in enumerate(doc["weights"])])
        lo, hi = (_number(c, f"clamp[{i}]", path) for i, c in enumerate(doc["clamp"]))
        if not 0.0 < lo <= hi:
            raise StrokeModelError(f"stroke-speed model {path}: clamp = [{lo}, {hi}] must satisfy 0 < low <= high")
        return StrokeModel(preset, tuple(names), bias, weights, (lo, hi), hashlib.sha256(raw).hexdigest()[:12])
