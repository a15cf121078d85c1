"""Per-shape swimming speed: a fitted model of how fast each swimmer shape's stroke carries it.

    morphmimic stroke-fit manta --shapes 200        # measure, fit, write the model

Won & Lee 2019 (METHOD.md A, "Reward normalization") scale a body's target velocity by its
mean leg length, `v_target = v0 (lbar / lbar0) max(0.5, 1 - sigma_l / lbar)` (a reconstruction);
for a swimmer the body length stands in for the legs (`rewards.Normalization`). In fluid that
rule misses most of what sets the speed: with the stroke tracked closely
(`common.tasks.shape.stroke_speed`) 200 random manta shapes swim 0.27-2.56 times their length-scaled
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

import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
import tyro

from common.config_limits import SEED, Limit, between, check_limits, validated
from common.tasks.shape.stroke_model import MODEL_DIR, StrokeModel, StrokeModelError
from learner.cli_options import parse_options, refuse

RIDGE = (1e-3, 1e-2, 1e-1, 1.0, 10.0)
"""Ridge strengths tried; the one with the lowest cross-validated error is kept."""
FOLDS = 5


def ridge_fit(x: np.ndarray, y: np.ndarray, lam: float) -> tuple[float, np.ndarray]:
    """(bias, weights) minimizing ||y - b - x w||^2 + lam ||w||^2 (the bias unpenalized)."""
    mx, my = x.mean(axis=0), y.mean()
    xc = x - mx
    w = np.linalg.solve(xc.T @ xc + lam * np.eye(x.shape[1]), xc.T @ (y - my))
    return float(my - mx @ w), w


def out_of_fold(x: np.ndarray, y: np.ndarray, lam: float, folds: int = FOLDS, seed: int = 0) -> np.ndarray:
    """Each sample's prediction of log ratio by the fit on the other folds."""
    idx = np.random.default_rng(seed).permutation(len(y))
    pred = np.empty(len(y))
    for part in np.array_split(idx, folds):
        train = np.setdiff1d(idx, part)
        b, w = ridge_fit(x[train], y[train], lam)
        pred[part] = b + x[part] @ w
    return pred


def cross_validated_rms(x: np.ndarray, y: np.ndarray, lam: float, folds: int = FOLDS, seed: int = 0) -> float:
    """Root-mean-square error of log ratio on held-out folds."""
    return float(np.sqrt(np.mean((y - out_of_fold(x, y, lam, folds, seed)) ** 2)))


def fit(params: np.ndarray, ratios: np.ndarray) -> dict:
    """Pick the ridge strength by cross-validation, fit on all samples; summary figures, in
    sample and held out (each shape predicted by the fit on the other folds). A "speed error"
    is |tracked speed - target| / target, what `morphmimic evaluate` reports for a swimmer."""
    x, y = np.log(params), np.log(ratios)
    cv = {lam: cross_validated_rms(x, y, lam) for lam in RIDGE}
    lam = min(cv, key=cv.get)
    b, w = ridge_fit(x, y, lam)
    held_out = y - out_of_fold(x, y, lam)
    resid = y - b - x @ w

    def speed_error_pct(r: np.ndarray) -> float:
        return float(100.0 * np.mean(np.abs(np.exp(r) - 1.0)))

    return {"bias": b, "weights": w.tolist(), "ridge": lam,
            "clamp": [float(ratios.min()), float(ratios.max())],
            "cv_rms_log": cv[lam], "fit_rms_log": float(np.sqrt(np.mean(resid ** 2))),
            "ratio_range": [float(ratios.min()), float(ratios.max())],
            "speed_error_pct_length_rule": speed_error_pct(y),
            "speed_error_pct_fit": speed_error_pct(resid),
            "speed_error_pct_held_out": speed_error_pct(held_out),
            "residual_ratio_range": [float(np.exp(resid.min())), float(np.exp(resid.max()))],
            "held_out_ratio_range": [float(np.exp(held_out.min())), float(np.exp(held_out.max()))]}


def measure(preset: str, shapes: int, seed: int, log=print) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]:
    """(names, params [n, d], tracked speed [n] m/s, length-scaled target [n] m/s) of `shapes`
    shapes drawn uniformly from the preset's shape box."""
    from common.tasks.registry import task_space  # lazy: start-up time of morphmimic stroke-fit --help (mujoco)
    # lazy: start-up time of morphmimic stroke-fit --help (mujoco)
    from common.tasks.shape.stroke_speed import stroke_speed
    from learner.presets import PRESETS  # lazy: start-up time of morphmimic stroke-fit --help (torch)

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


def base_ratio(preset: str) -> float:
    """The base body's tracked stroke speed over its clip's speed (1 when the clip is calibrated)."""
    # lazy: start-up time of morphmimic stroke-fit --help (mujoco)
    from common.tasks.shape.stroke_speed import stroke_speed

    s = stroke_speed(preset)
    return s.speed_m_s / s.clip_speed_m_s


def _refit_samples(path: Path) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray, dict]:
    """The measurements stored in a model file (see `main --refit`)."""
    try:
        doc = json.loads(path.read_text())
        smp = doc["samples"]
        names = tuple(str(n) for n in doc["names"])
        params = np.asarray(smp["params"], dtype=np.float64)
        speeds = np.asarray(smp["speed_m_s"], dtype=np.float64)
        targets = np.asarray(smp["target_m_s"], dtype=np.float64)
    except (OSError, ValueError, KeyError, TypeError, OverflowError, RecursionError) as e:
        raise StrokeModelError(f"--refit: {path} holds no readable samples ({type(e).__name__}: {e})") from None
    n = len(speeds)
    if params.shape != (n, len(names)) or targets.shape != (n,) or n < 20:
        raise StrokeModelError(f"--refit: {path} has params {params.shape}, speeds {speeds.shape}, targets "
                               f"{targets.shape}; need at least 20 shapes over {len(names)} parameters")
    if not (np.isfinite(params).all() and (params > 0).all()):
        raise StrokeModelError(f"--refit: {path}: every shape parameter must be a finite positive number")
    seed, base = doc.get("seed", 0), doc.get("base_ratio")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise StrokeModelError(f"--refit: {path}: seed = {seed!r} must be an integer >= 0")
    if base is not None and (isinstance(base, bool) or not isinstance(base, (int, float)) or not 0 < base < 1e3):
        raise StrokeModelError(f"--refit: {path}: base_ratio = {base!r} must be a positive number")
    return names, params, speeds, targets, doc


PROG = "morphmimic stroke-fit"


@validated
@dataclass
class StrokeFitOptions:
    preset: tyro.conf.Positional[Literal["fish", "manta"]]
    """The swimmer whose shapes to measure."""
    shapes: int = 200
    """Random shapes to measure (the fit has up to 27 weights)."""
    seed: int = 0
    """Seed of the shape draws."""
    out: Path | None = None
    """Model file (default: common/data/stroke_speed/<preset>.json)."""
    refit: bool = False
    """Fit again from the measurements stored in the model file, without measuring."""
    force: bool = False
    """Measure anew over an existing model file (runs and evaluations that use it change targets)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"shapes": between(20, 5000, integer=True), "seed": SEED}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(StrokeFitOptions, argv, prog=PROG, description=__doc__)
    out = args.out or MODEL_DIR / f"{args.preset}.json"
    if args.refit:
        try:
            names, params, speeds, targets, old = _refit_samples(out)
        except StrokeModelError as e:
            refuse(PROG, str(e))
        shapes, seed, base = len(speeds), old.get("seed", args.seed), old.get("base_ratio")
    else:
        if out.exists() and not args.force:
            refuse(PROG, f"{out} exists: a new measurement changes the targets of every run and evaluation that uses it; "
                         "give --force to replace it, --refit to fit its stored measurements again, or --out")
        names, params, speeds, targets = measure(args.preset, args.shapes, args.seed)
        shapes, seed, base = args.shapes, args.seed, None
    ratios = speeds / targets
    if not (np.isfinite(ratios).all() and (ratios > 0).all()):
        refuse(PROG, f"{args.preset}: a shape swam backwards or not at all (ratios {ratios.min():.3f}-{ratios.max():.3f}); no model written")
    summary = fit(params, ratios)
    base = base_ratio(args.preset) if base is None else float(base)
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = {"preset": args.preset, "names": list(names), **summary, "seed": seed,
           "base_ratio": base, "base_ratio_predicted": math.exp(summary["bias"]),
           "command": f"morphmimic stroke-fit {args.preset} --shapes {shapes} --seed {seed}",
           "samples": {"params": params.round(6).tolist(), "speed_m_s": speeds.round(6).tolist(),
                       "target_m_s": targets.round(6).tolist()}}
    out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"{args.preset}: {shapes} shapes swim x{summary['ratio_range'][0]:.2f}-x{summary['ratio_range'][1]:.2f} "
          f"their length-scaled target ({summary['speed_error_pct_length_rule']:.1f}% mean speed error for a "
          f"perfectly tracked stroke); against the fitted target x{summary['residual_ratio_range'][0]:.2f}-"
          f"x{summary['residual_ratio_range'][1]:.2f} ({summary['speed_error_pct_fit']:.1f}%) in sample, "
          f"x{summary['held_out_ratio_range'][0]:.2f}-x{summary['held_out_ratio_range'][1]:.2f} "
          f"({summary['speed_error_pct_held_out']:.1f}%) held out; ridge {summary['ridge']:g}; "
          f"base body x{base:.2f} measured, x{math.exp(summary['bias']):.2f} predicted; wrote {out}")
    return 0
