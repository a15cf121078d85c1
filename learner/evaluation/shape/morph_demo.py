"""The morph demo (Won & Lee 2019, Figure 1; METHOD.md A "Shape change on the fly"): the body
changes shape while the trained controller runs, and the episode is recorded.

    morphmimic evaluate --checkpoint learner/pretrained/lower_biped --morph
    python -m learner.evaluation.shape.morph_demo --checkpoint learner/pretrained/lower_biped --strength 0.5 --gif

The schedule is a list of keyframes `(time_s, {shape parameter: value})`, linearly
interpolated (parameters not named stay at the base shape's value, 1.0); the body is rebuilt every
`--every` control steps (`ImitateEnv.set_shape`: state carried over, lifted out of the floor,
reference retargeted). Defaults per parameterization follow Figure 1: tall, then half height
(short), then long limbs, then back. `--strength s` scales every keyframe's deviation from the base
(s = 0.5: a moderate morph). Writes `morph.png` (strip), `morph.gif` (with --gif) and
`morph.json` (the schedule, whether and when it fell) into `--out`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from learner.evaluation import cli_args, harness
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
    from common.tasks.registry import make_env

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


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m learner.evaluation.shape.morph_demo", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--checkpoint", required=True)
    p.add_argument("--out", default="", help="output directory (default: <checkpoint dir>/morph)")
    p.add_argument("--schedule", type=cli_args.morph_schedule, default=None,
                   help='JSON keyframes, e.g. \'[[0, {}], [3, {"global_z": 1.3}], [6, {}]]\'')
    p.add_argument("--strength", type=cli_args.finite_float, default=1.0, help="scale of every keyframe's deviation from the base shape")
    p.add_argument("--every", type=cli_args.positive_int, default=1, help="rebuild the body every this many control steps")
    p.add_argument("--gif", action="store_true", help="also write morph.gif")
    args = p.parse_args(argv)
    loaded = checkpoint.load_trained(args.checkpoint)
    schedule = args.schedule
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


if __name__ == "__main__":
    import sys

    raise SystemExit(main(sys.argv[1:]))
