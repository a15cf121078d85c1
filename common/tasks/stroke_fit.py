"""Per-shape swimming speed: a fitted model of how fast each swimmer shape's stroke carries it.

    python -m common.tasks.stroke_fit manta --shapes 200        # measure, fit, write the model

Won & Lee 2019 (METHOD.md A, "Reward normalization") scale a body's target velocity by its
mean leg length, `v_target = v0 (lbar / lbar0) max(0.5, 1 - sigma_l / lbar)` (a reconstruction);
for a swimmer the body length stands in for the legs (`rewards.Normalization`). In fluid that
rule misses most of what sets the speed: with the stroke tracked closely
(`common.tasks.stroke_speed`) random manta shapes swim 0.64-1.65 times their length-scaled
target, so a policy that imitates the stroke, which 9 of the reward's 10.5 weight asks for,
misses the speed term by whatever its shape's stroke gives. `--task.imitate.swimmer-speed
stroke_fit` asks each shape instead for the speed its own tracked stroke reaches, predicted by
this module's model (a deviation from the paper, stated wherever figures are compared):

    log(speed / length-scaled target) = b + w . log(shape parameters)

fitted by ridge regression on `--shapes` random shapes of the preset's parameterization, each
measured by `stroke_speed.stroke_speed` (close-tracking PD, zero action, 5-20 s). The model,
its measurements and its cross-validated error are written to
`common/data/stroke_speed/<preset>.json` and loaded by the task (`StrokeModel.load`).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MODEL_DIR = Path(__file__).resolve().parents[1] / "data" / "stroke_speed"
RIDGE = (1e-3, 1e-2, 1e-1, 1.0, 10.0)
"""Ridge strengths tried; the one with the lowest cross-validated error is kept."""
FOLDS = 5


class StrokeModelError(ValueError):
    """A stroke-speed model file that is missing, malformed or for another shape space."""


@dataclass(frozen=True)
class StrokeModel:
    """`ratio(shape) = exp(bias + weights . log(shape))`: the speed a shape's tracked stroke
    reaches over its length-scaled target (see the module docstring)."""

    preset: str
    names: tuple[str, ...]
    bias: float
    weights: np.ndarray  # [len(names)]

    def ratio(self, shape: np.ndarray) -> float:
        x = np.log(np.asarray(shape, dtype=np.float64))
        return float(np.exp(self.bias + self.weights @ x))

    @staticmethod
    def load(preset: str, names: tuple[str, ...], path: Path | None = None) -> StrokeModel:
        """The model of `preset` over the shape parameters `names`; StrokeModelError naming the
        file and what is wrong if it is missing, malformed or fitted on other parameters."""
        path = Path(path or MODEL_DIR / f"{preset}.json")
        try:
            doc = json.loads(path.read_text())
        except FileNotFoundError:
            raise StrokeModelError(f"stroke-speed model {path} not found: make it with "
                                   f"`python -m common.tasks.stroke_fit {preset}`") from None
        except (OSError, ValueError) as e:
            raise StrokeModelError(f"stroke-speed model {path}: not readable JSON ({e})") from None
        try:
            got_names = tuple(str(n) for n in doc["names"])
            bias = float(doc["bias"])
            weights = np.asarray(doc["weights"], dtype=np.float64)
            got_preset = str(doc["preset"])
        except (KeyError, TypeError, ValueError) as e:
            raise StrokeModelError(f"stroke-speed model {path}: needs preset, names, bias and weights ({e!r})") from None
        if got_preset != preset or got_names != tuple(names):
            raise StrokeModelError(f"stroke-speed model {path} is for {got_preset!r} over {len(got_names)} parameters; "
                                   f"the task needs {preset!r} over {list(names)}")
        if weights.shape != (len(names),) or not (math.isfinite(bias) and np.isfinite(weights).all()):
            raise StrokeModelError(f"stroke-speed model {path}: bias and {len(names)} weights must be finite numbers")
        return StrokeModel(preset, got_names, bias, weights)


def ridge_fit(x: np.ndarray, y: np.ndarray, lam: float) -> tuple[float, np.ndarray]:
    """(bias, weights) minimizing ||y - b - x w||^2 + lam ||w||^2 (the bias unpenalized)."""
    mx, my = x.mean(axis=0), y.mean()
    xc = x - mx
    w = np.linalg.solve(xc.T @ xc + lam * np.eye(x.shape[1]), xc.T @ (y - my))
    return float(my - mx @ w), w


def cross_validated_rms(x: np.ndarray, y: np.ndarray, lam: float, folds: int = FOLDS, seed: int = 0) -> float:
    """Root-mean-square error of log ratio on held-out folds."""
    idx = np.random.default_rng(seed).permutation(len(y))
    errs = []
    for part in np.array_split(idx, folds):
        train = np.setdiff1d(idx, part)
        b, w = ridge_fit(x[train], y[train], lam)
        errs.append(y[part] - b - x[part] @ w)
    return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))


def fit(params: np.ndarray, ratios: np.ndarray) -> dict:
    """Pick the ridge strength by cross-validation, fit on all samples; summary figures."""
    x, y = np.log(params), np.log(ratios)
    cv = {lam: cross_validated_rms(x, y, lam) for lam in RIDGE}
    lam = min(cv, key=cv.get)
    b, w = ridge_fit(x, y, lam)
    resid = y - b - x @ w
    return {"bias": b, "weights": w.tolist(), "ridge": lam,
            "cv_rms_log": cv[lam], "fit_rms_log": float(np.sqrt(np.mean(resid ** 2))),
            "ratio_range": [float(ratios.min()), float(ratios.max())],
            "residual_ratio_range": [float(np.exp(resid.min())), float(np.exp(resid.max()))]}


def measure(preset: str, shapes: int, seed: int, log=print) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]:
    """(names, params [n, d], tracked speed [n] m/s, length-scaled target [n] m/s) of `shapes`
    shapes drawn uniformly from the preset's shape box."""
    from common.tasks.registry import task_space
    from common.tasks.stroke_speed import stroke_speed
    from learner.presets import PRESETS

    task = PRESETS[preset][1].task
    space = task_space(task)
    n_shape = space.dim - len(task.imitate.task_params)
    lo, hi = space.low_array[:n_shape], space.high_array[:n_shape]
    rng = np.random.default_rng(seed)
    params, speeds, targets = np.empty((shapes, n_shape)), np.empty(shapes), np.empty(shapes)
    t0 = time.time()
    for i in range(shapes):
        params[i] = rng.uniform(lo, hi)
        s = stroke_speed(preset, params=params[i])
        speeds[i], targets[i] = s.speed_m_s, s.clip_speed_m_s
        log(f"shape {i + 1}/{shapes}: {s.speed_m_s:.3f} m/s against {s.clip_speed_m_s:.3f} "
            f"(x{s.speed_m_s / s.clip_speed_m_s:.2f}), {time.time() - t0:.0f} s")
    return space.names[:n_shape], params, speeds, targets


def main(argv: list[str] | None = None) -> int:
    from common.tasks.stroke_speed import SWIMMERS

    p = argparse.ArgumentParser(prog="python -m common.tasks.stroke_fit", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("preset", choices=SWIMMERS, help="the swimmer whose shapes to measure")
    p.add_argument("--shapes", type=int, default=200, help="random shapes to measure (>= 20)")
    p.add_argument("--seed", type=int, default=0, help="seed of the shape draws")
    p.add_argument("--out", type=Path, default=None, help="model file (default: common/data/stroke_speed/<preset>.json)")
    args = p.parse_args(argv)
    if not 20 <= args.shapes <= 5000:
        p.error(f"--shapes {args.shapes}: give 20 to 5000 (the fit has up to 27 weights)")
    names, params, speeds, targets = measure(args.preset, args.shapes, args.seed)
    ratios = speeds / targets
    if not (np.isfinite(ratios).all() and (ratios > 0).all()):
        p.error(f"{args.preset}: a shape swam backwards or not at all (ratios {ratios.min():.3f}-{ratios.max():.3f}); no model written")
    summary = fit(params, ratios)
    out = args.out or MODEL_DIR / f"{args.preset}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = {"preset": args.preset, "names": list(names), **summary,
           "command": f"python -m common.tasks.stroke_fit {args.preset} --shapes {args.shapes} --seed {args.seed}",
           "samples": {"params": params.round(6).tolist(), "speed_m_s": speeds.round(6).tolist(),
                       "target_m_s": targets.round(6).tolist()}}
    out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"{args.preset}: {args.shapes} shapes swim x{summary['ratio_range'][0]:.2f}-x{summary['ratio_range'][1]:.2f} "
          f"their length-scaled target; after the fit x{summary['residual_ratio_range'][0]:.2f}-"
          f"x{summary['residual_ratio_range'][1]:.2f} (held-out rms {100 * summary['cv_rms_log']:.1f}% in log), "
          f"ridge {summary['ridge']:g}; wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
