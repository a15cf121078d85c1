"""`morphmimic evaluate --checkpoint <executor> --morph`: the body changes while the executor
tracks a clip (issue 55 item 3; Won & Lee 2019's Figure 1 morph, on UniCon's executor).

    morphmimic evaluate --checkpoint runs/executor-shape --morph                       # humanoid3d_walk
    morphmimic evaluate --checkpoint runs/executor-shape --morph --clips humanoid3d_run --strength 0.5 --gif

What it runs: the checkpoint's evaluation task (`evaluate.eval_task`) with the body varying
(`evaluate.shape_task`), the clip from its first frame, replayed from a random frame of it (seeded)
each time it ends (the dataset scheduler's reschedule, placed under the character) until the
schedule's last keyframe. The shape follows the schedule's keyframes (`(time_s, {parameter:
value})`, interpolated linearly; parameters not named stay at the base body's value, deviations
scaled by `--strength`, clipped to the box), and every `--every` control steps the body is changed
mid-episode by `ExecutorEnv.set_shape`: the new body is built (cached), the character's qpos, qvel
and time are copied onto it, the root moved so the body's lowest point stays at its height (then
lifted if another limb reaches into the floor), and the tracked clip is re-read retargeted onto
the new body at the same clip time, moved horizontally so its root stays where the old target's
was. The observation the next action is chosen from is the new body's (its shape first in it).

The same episode (clip, seed, reschedules) runs a second time on the base body without morphing,
for comparison. Both are read as `evaluate.run_episode` reads an evaluation episode: the first
step at which UniCon's per-term rule fails, PHC's criterion, MPJPE. Writes `morph.json`,
`morph.png` (a strip) and with --gif `morph.gif` into `--out` (default `<checkpoint dir>/morph`).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from common.tasks.registry import make_env
from learner import checkpoint
from learner.evaluation.executor import evaluate as xe
from learner.evaluation.executor.camera import CameraView
from learner.evaluation.shape import morph_demo
from learner.evaluation.shape import plots as eval_plots

SCHEDULES = {
    "height_thickness": [(0.0, {}), (1.0, {}), (3.0, {"height": 1.4}), (4.0, {"height": 1.4}), (6.0, {"height": 0.8}),
                         (7.0, {"height": 0.8}), (9.0, {"thickness": 1.4}), (10.0, {"thickness": 1.4}),
                         (11.5, {"thickness": 0.6}), (12.5, {"thickness": 0.6}), (14.0, {})],
    "upper_lower_thickness": [(0.0, {}), (1.0, {}), (3.0, {"upper_thickness": 1.4}), (4.0, {"upper_thickness": 1.4}),
                              (6.0, {"lower_thickness": 1.4}), (7.0, {"lower_thickness": 1.4}), (9.0, {})],
    "left_right_leg": [(0.0, {}), (1.0, {}), (3.0, {"left_leg": 1.1, "right_leg": 0.9}), (4.0, {"left_leg": 1.1, "right_leg": 0.9}),
                       (6.0, {}), (7.0, {})],
    **morph_demo.SCHEDULES,
}
"""Default keyframes per parameterization of the humanoid (the shape controllers' where they share one)."""
DEFAULT_CLIP = "humanoid3d_walk"


def morph_task(cfg, clip_id: str, seconds: float):
    """The evaluation task with the body varying, tracking `clip_id` alone for `seconds`, the clip
    replayed (rescheduled from a drawn frame, placed under the character) at its end."""
    task = xe.eval_task(cfg, shapes=True)
    ex = dataclasses.replace(task.executor, clips=(clip_id,), split="all", at_clip_end="reschedule")
    return dataclasses.replace(task, episode_s=seconds, executor=ex)


def run_morph(loaded: checkpoint.Loaded, clip_id: str = DEFAULT_CLIP, schedule=None, strength: float = 1.0,
              every: int = 1, seed: int = 0, recorder=None, morph: bool = True) -> dict[str, Any]:
    """One episode on `clip_id` from its first frame, its body following `schedule` (default per
    parameterization, `SCHEDULES`) with `morph`, else on the base body throughout; the
    `evaluate.run_episode` record plus the shape changes made ("morphs") and
    the body's shape every second of simulation ("shapes": [step, [values]], after that step's change)."""
    param = loaded.cfg.task.body.parameterization
    schedule = list(schedule or SCHEDULES.get(param) or [])
    if not schedule:
        raise ValueError(f"no default morph schedule for parameterization {param!r}; pass --schedule")
    seconds = float(schedule[-1][0])
    if seconds <= 0:
        raise ValueError(f"the schedule's last keyframe is at {seconds:g} s: it must be later than 0")
    env = make_env(morph_task(loaded.cfg.task, clip_id, seconds), seed=0)
    policy = checkpoint.make_policy(loaded, env.obs_dim, env.act_dim)
    space, n = env.space, env.space.dim
    try:
        start = morph_demo.shape_at(schedule, 0.0, space, n, strength) if morph else space.default_array
    except SystemExit as exc:  # an unknown parameter name
        raise ValueError(str(exc)) from None
    changes, trail = [0], []
    every_second = max(1, int(round(1.0 / env.dt)))

    def on_step(e, k: int):
        if recorder is not None:
            recorder(e, k)
        seen = None
        if morph and k % every == 0:
            target = morph_demo.shape_at(schedule, k * e.dt, space, n, strength)
            if np.abs(target - e.params).max() > 1e-9:
                e.set_shape(target)
                changes[0] += 1
                seen = e.observe_now()
        if k % every_second == 0:
            trail.append([k, [float(x) for x in e.params]])
        return seen

    rec = xe.run_episode(env, policy, clip_id, 0.0, loaded.cfg.task.executor.termination, seed, on_step=on_step,
                         params=start)
    dt = env.dt
    return {**rec, "morph": morph, "morphs": changes[0], "seconds": rec["steps"] * dt, "planned_seconds": seconds,
            "fail_s": None if rec["fail_step"] is None else rec["fail_step"] * dt,
            "phc_fail_s": None if rec["phc_fail_step"] is None else rec["phc_fail_step"] * dt,
            "shapes": trail, "names": list(space.names)}


def run(loaded: checkpoint.Loaded, clip_id: str, out: Path, schedule=None, strength: float = 1.0, every: int = 1,
        gif: bool = False, seed: int = 0) -> dict[str, Any]:
    """The morph episode and its base-body twin; writes morph.json, morph.png (and morph.gif)."""
    rec = eval_plots.Recorder(every=3 if gif else 15)
    morphed = run_morph(loaded, clip_id, schedule, strength, every, seed, lambda e, k: rec(CameraView(e), k))
    rec.close()
    fixed = run_morph(loaded, clip_id, schedule, strength, every, seed, morph=False)
    out.mkdir(parents=True, exist_ok=True)
    files = [rec.write_strip(out / "morph.png", n=12)]
    if gif:
        files.append(rec.write_gif(out / "morph.gif", 20.0))
    result = {"checkpoint": str(loaded.path), "clip_id": clip_id, "strength": strength, "every": every, "seed": seed,
              "schedule": [list(k) for k in (schedule or SCHEDULES[loaded.cfg.task.body.parameterization])],
              "morph": morphed, "base_body": fixed, "files": [str(f) for f in files if f is not None]}
    (out / "morph.json").write_text(json.dumps(result, indent=1) + "\n")
    result["files"].append(str(out / "morph.json"))
    return result


def describe(r: dict) -> str:
    """One run's outcome in a few words."""
    rule = "held UniCon's rule throughout" if r["fail_s"] is None else f"broke UniCon's rule at {r['fail_s']:.1f} s"
    phc = "never lost the target" if r["phc_fail_s"] is None else f"lost the target (PHC) at {r['phc_fail_s']:.1f} s"
    return f"{rule}, {phc}, MPJPE {'-' if r['mpjpe_mm'] is None else format(r['mpjpe_mm'], '.0f')} mm"
