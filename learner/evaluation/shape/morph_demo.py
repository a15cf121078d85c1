"""The morph demo (Won & Lee 2019, Figure 1; METHOD.md A "Shape change on the fly"): the body
changes shape while the trained controller runs, and the episode is recorded.

    morphmimic evaluate --checkpoint learner/pretrained/lower_biped --morph
    morphmimic evaluate --checkpoint learner/pretrained/lower_biped --morph --strength 0.5 --gif

The schedule is a list of keyframes `(time_s, {shape parameter: value})`, linearly
interpolated (parameters not named stay at the base shape's value, 1.0); the body is rebuilt every
`--every` control steps (`ImitateEnv.set_shape`: state carried over, lifted out of the floor,
reference retargeted). Defaults per parameterization follow Figure 1: tall, then half height
(short), then long limbs, then back. `--strength s` scales every keyframe's deviation from the base
(s = 0.5: a moderate morph). Writes `morph.png` (strip), `morph.gif` (with --gif) and
`morph.json` (the schedule, whether and when it fell) into `--out`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, ClassVar

import numpy as np

from common.config_limits import FINITE, Limit, at_least, check_limits, validated
from common.tasks.registry import make_env
from learner.cli_options import parse_options
from learner.evaluation import harness
from learner.evaluation.shape import episodes
from learner import checkpoint

from learner.evaluation.shape import plots as eval_plots

SCHEDULES = {
    "leg_arm": [(0.0, {}), (1.5, {}), (4.0, {"leg_length": 1.5}), (6.0, {"leg_length": 1.5}), (8.5, {"leg_length": 0.6}),
                (10.5, {"leg_length": 0.6}), (12.5, {"arm_length": 1.5}), (14.5, {"arm_length": 1.5}), (16.5, {}), (18.0, {})],
    "random": [(0.0, {}), (1.5, {}), (4.0, {"global_z": 1.4}), (6.0, {"global_z": 1.4}), (8.5, {"global_z": 0.6}),
               (10.5, {"global_z": 0.6}), (12.5, {"global_x": 1.4, "global_y": 1.4}),
               (14.5, {"global_x": 1.4, "global_y": 1.4}), (16.5, {}), (18.0, {})],
    "uniform": [(0.0, {}), (1.5, {}), (4.0, {"scale": 1.4}), (6.0, {"scale": 1.4}), (8.5, {"scale": 0.6}),
                (10.5, {"scale": 0.6}), (12.5, {}), (14.0, {})],
}
"""Default keyframes per parameterization (Figure 1: tall, half height, long/wide, back)."""


def shape_at(schedule, t_s: float, space, n_shape: int, strength: float) -> np.ndarray:
    """The scheduled shape `[n_shape]` at time t_s, deviations from the base scaled by strength,
    clipped to the box."""
    times = np.array([k[0] for k in schedule])
    base = space.default_array[:n_shape]
    keys = []
    for _, values in schedule:
        v = base.copy()
        for name, x in values.items():
            if name not in space.names[:n_shape]:
                raise SystemExit(f"schedule parameter {name!r} is not one of {list(space.names[:n_shape])}")
            i = space.names.index(name)
            v[i] = base[i] + strength * (x - base[i])
        keys.append(v)
    keys = np.array(keys)
    out = np.array([np.interp(t_s, times, keys[:, i]) for i in range(n_shape)])
    return np.clip(out, space.low_array[:n_shape], space.high_array[:n_shape])


def run_morph(loaded: checkpoint.Loaded, schedule=None, strength: float = 1.0, every: int = 1, seed: int = 0,
              recorder=None) -> dict:
    """Run one episode at the base shape, morphing along `schedule` (default per
    parameterization); returns {"fell", "seconds", "morphs", "schedule"}."""
    schedule = schedule or SCHEDULES.get(loaded.cfg.task.body.parameterization)
    if not schedule:
        raise SystemExit(f"no default morph schedule for parameterization {loaded.cfg.task.body.parameterization!r}; "
                         f"pass --schedule")
    seconds = float(schedule[-1][0])
    env = make_env(harness.eval_task(loaded.cfg.task, seconds), seed=0)
    policy = checkpoint.make_policy(loaded, env.obs_dim, env.act_dim)
    n_shape = env.n_shape
    params = env.space.default_array.copy()
    params[:n_shape] = shape_at(schedule, 0.0, env.space, n_shape, strength)
    morphs = [0]

    def on_step(env, k: int) -> None:
        if recorder is not None:
            recorder(env, k)
        if k % every == 0:
            target = shape_at(schedule, k * env.dt, env.space, n_shape, strength)
            if np.abs(target - env.params[:n_shape]).max() > 1e-6:
                env.set_shape(target)
                morphs[0] += 1

    result = episodes.run_episode(env, policy, params, seed, on_step=on_step)
    return {"fell": result["fell"], "seconds": result["seconds"], "planned_seconds": seconds, "morphs": morphs[0],
            "return": result["return"], "strength": strength, "schedule": schedule}


def morph_schedule(text: str) -> tuple[tuple[float, dict[str, float]], ...]:
    """JSON keyframes `[[time_s, {parameter: value}], ...]` with times >= 0 and strictly
    increasing (the morph interpolates between them) and finite values; ValueError naming the
    value otherwise. Parameter names are checked against the checkpoint's shape space when the
    schedule is used (`shape_at`)."""
    allowed = 'JSON keyframes [[time_s, {"parameter": value}], ...] with times >= 0 strictly increasing'
    try:
        raw = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{text!r} is not JSON ({exc.msg}); it must be {allowed}") from None
    if not isinstance(raw, list) or not raw:
        raise ValueError(f"{text!r} must be a non-empty list of {allowed}")
    keys: list[tuple[float, dict[str, float]]] = []
    for k in raw:
        ok = isinstance(k, list) and len(k) == 2 and isinstance(k[1], dict)
        t = k[0] if ok else None
        if not ok or isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
            raise ValueError(f"keyframe {json.dumps(k)} in {text!r}: each must be [time_s >= 0, {{...}}]")
        for name, v in k[1].items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"keyframe {json.dumps(k)}: {name} = {v!r} must be a finite number")
        if keys and t <= keys[-1][0]:
            raise ValueError(f"keyframe times {[kk[0] for kk in keys] + [t]} must be strictly increasing")
        keys.append((float(t), {str(n): float(v) for n, v in k[1].items()}))
    return tuple(keys)


Schedule = Annotated[tuple, harness.one_value(morph_schedule, "JSON", lambda keys: json.dumps(keys) if keys else "")]
"""`--schedule '[[0, {}], [3, {"global_z": 1.3}], [6, {}]]'`: keyframes (empty: the default schedule)."""


@validated
@dataclass(kw_only=True)
class MorphOptions:
    """The morph demo's options (`morphmimic evaluate --morph` passes them on)."""

    checkpoint: str
    """Checkpoint dir, state.pt, run dir or learner/pretrained/<name>."""
    out: str = ""
    """Output directory (default: <checkpoint dir>/morph)."""
    schedule: Schedule = ()
    """JSON keyframes, e.g. '[[0, {}], [3, {"global_z": 1.3}], [6, {}]]' (default: the parameterization's)."""
    strength: float = 1.0
    """Scale of every keyframe's deviation from the base shape."""
    every: int = 1
    """Rebuild the body every this many control steps."""
    gif: bool = False
    """Also write morph.gif."""

    LIMITS: ClassVar[dict[str, Limit]] = {"strength": FINITE, "every": at_least(1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def main(argv: list[str]) -> int:
    return run(parse_options(MorphOptions, argv, prog="morphmimic evaluate --morph", description=__doc__))


def run(args: MorphOptions) -> int:
    """Run the morph demo and write its files (see the module docstring)."""
    loaded = checkpoint.load_trained(args.checkpoint)
    schedule = list(args.schedule) or None
    out = Path(args.out) if args.out else loaded.path.parent / "morph"
    rec = eval_plots.Recorder(every=3 if args.gif else 15)
    result = run_morph(loaded, schedule, args.strength, args.every, recorder=rec)
    rec.close()
    files = [rec.write_strip(out / "morph.png", n=12)]
    if args.gif:
        files.append(rec.write_gif(out / "morph.gif", 10.0))
    out.mkdir(parents=True, exist_ok=True)
    (out / "morph.json").write_text(json.dumps(result, indent=1) + "\n")
    state = f"fell after {result['seconds']:.1f} s" if result["fell"] else f"stayed up for {result['seconds']:.1f} s"
    print(f"[morph] {loaded.name}: {result['morphs']} shape changes, {state}; wrote "
          + ", ".join(str(f) for f in files if f) + f", {out / 'morph.json'}")
    return 0
