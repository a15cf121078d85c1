"""`morphmimic robustness --checkpoint X`: UniCon's zero-shot robustness tests (Table 2, METHOD.md
B "Evaluation") on one checkpoint: the reference played slower or faster, projectiles thrown at
the character, a heavier and a lighter body, none of which the policy saw in training; and one
row more than Table 2, "shape": the same episodes on random body shapes (issue 55 item 3).

    morphmimic robustness --checkpoint runs/executor                         # train-split clips, 3 starts each
    morphmimic robustness --checkpoint runs/executor --clips humanoid3d_cartwheel --starts 10   # the paper's clip
    morphmimic robustness --checkpoint runs/executor --rows speed,mass --workers 2
    morphmimic robustness --checkpoint learner/pretrained/lower_biped --shapes 20 --episode-s 10   # a shape controller

Each row is performance relative to the same episodes unperturbed. Performance: the mean over
the episodes of the return under the checkpoint's own termination rule divided by the
episode's planned length in control steps (the clip segment at that playback speed for the
executor, the episode length for a shape controller): the mean reward per planned step, a step
after termination counting 0. The raw return would reward slow playback (x0.5 takes twice the
steps), so it is normalized; for rows at normal speed the two agree up to each episode's fixed
length. UniCon measures with "the reward" too. Also reported per row: success %.

Executor: episodes on the `--clips` (default: the clips the checkpoint trained on) from
`--starts` frames each, exactly as `morphmimic evaluate` runs them (`learner/evaluation/executor/evaluate.py`);
success = tracked to the clip's end with no reward term below alpha.
The executor's shape row: `--shapes` (default 10) shapes drawn uniformly from the box of the
checkpoint's parameterization with `--seed`, every (clip, start) on each, run as `morphmimic
evaluate --shapes` runs them (the body built per episode, the clip retargeted onto it); a
checkpoint trained on the base body only meets them zero-shot.
Shape controllers (Won & Lee walkers and swimmers): `--shapes` random shapes (fixed `--seed`),
`--episode-s` episodes; success = did not fall. Mass rows apply to every one; speed rows only to
a checkpoint trained with the "speed" task parameter (its playback speed is an observed episode
parameter); projectile rows to none (the shape tasks have no projectile body). Skipped rows are
listed with the reason. A task the registry does not list `robustness` for (reach: an arm without
gravity, nothing to push) is refused in one line (`common.tasks.registry.command_refusal`).

The projectile (`ExecutorEnv.throw_projectile`, a 2 kg ball of 8 cm radius) is launched at
`--projectile-speed` (10 m/s) from `--projectile-distance` (2 m) straight at the root, at steps
0, N, 2N, ... of each episode. The scene holds `PROJECTILES` (24) balls thrown in turn, each
parked again 1 s after its throw, so even a throw every control step has balls arriving while
the next ones fly (12 control steps of flight at the defaults); a row whose interval times the
ball count is shorter than a flight is skipped, since balls would be re-thrown before they land.

Writes into `--out` (default `<checkpoint dir>/robustness`): `robustness.md` (the table, UniCon's
and DeepMimic's figures beside each row, the projectile described), `robustness.json`,
`robustness.png` (relative performance against speed factor and projectile interval, the
paper's figures as a second line). Prints one line per row.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar

import numpy as np
import torch

from common.config_limits import SEED, Limit, above, at_least, check_limits, validated
from learner.cli_options import parse_options, refuse
from learner.evaluation import harness, registry
from learner.evaluation.shape import episodes
from learner import checkpoint

from learner.evaluation.executor import evaluate as xe
from learner.evaluation.executor import robustness_report
from learner.evaluation.executor.report import Clips, Settings, select_clips
from learner.progress import Progress
from common.characters.mass import scale_body_mass, set_body_mass
from common.tasks.executor.env import PROJECTILES
from common.tasks.registry import make_env, task_space

SPEEDS = (0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6)
PROJECTILE_EVERY = (1, 5, 10, 20, 30, 40, 50, 60, 70, 80)
MASSES = {"heavy": 1.25, "light": 0.75}
UNICON_TABLE2 = {
    "speed": {1.6: (65.8, 21.5), 1.5: (76.9, 20.2), 1.4: (88.7, 21.5), 1.3: (95.9, 22.5), 1.2: (98.5, 27.4),
              1.1: (98.0, 38.1), 0.9: (99.2, 36.3), 0.8: (96.6, 22.2), 0.7: (91.7, 15.0), 0.6: (70.0, 13.7),
              0.5: (47.4, 10.8), 0.4: (34.5, 8.1)},
    "projectile": {1: (31.6, 13.2), 5: (69.9, 27.7), 10: (86.8, 37.5), 20: (95.9, 51.7), 30: (97.1, 60.0),
                   40: (98.0, 63.0), 50: (98.7, 62.0), 60: (98.7, 65.2), 70: (98.9, 63.9), 80: (99.2, 68.8)},
    "mass": {"heavy": (77.9, 65.7), "light": (98.2, 33.5)},
}
"""UniCon 2020 Table 2: relative performance (%) on a cartwheel clip, (UniCon, DeepMimic)."""
GROUPS = ("speed", "projectile", "mass", "shape")
"""Row groups: Table 2's three, and the body's shape (issue 55 item 3)."""
EXECUTOR_SHAPES = 10
"""The executor's shape row: random shapes, each running every (clip, start) of the other rows."""
SHAPE_SEED = 2019
PROJECTILE_SPEED_MPS = 10.0
PROJECTILE_DISTANCE_M = 2.0


@dataclass(frozen=True)
class Row:
    """One row of the table: its group, name, what it changes, and the paper's figures."""

    group: str
    name: str
    perturbation: xe.Perturbation
    paper: tuple[float, float] | None = None

    @property
    def x(self) -> float:
        """The row's value on its plot axis: speed factor, throw interval (steps), mass factor."""
        p = self.perturbation
        return {"speed": p.speed, "projectile": float(p.projectile_every), "mass": p.mass, "shape": float(p.shapes)}[self.group]


def rows_for(groups: tuple[str, ...], projectile_speed: float = PROJECTILE_SPEED_MPS,
             projectile_distance: float = PROJECTILE_DISTANCE_M, shapes: int = EXECUTOR_SHAPES,
             seed: int = SHAPE_SEED) -> list[Row]:
    """Table 2's rows of the chosen groups, in the paper's order within each group; the "shape"
    group (not in Table 2): one row, the same episodes on `shapes` random body shapes (`seed`)."""
    out: list[Row] = []
    if "speed" in groups:
        out += [Row("speed", f"speed x{s:g}", xe.Perturbation(speed=s), UNICON_TABLE2["speed"][s]) for s in SPEEDS]
    if "projectile" in groups:
        out += [Row("projectile", f"projectile every {n}", xe.Perturbation(
            projectile_every=n, projectile_speed_mps=projectile_speed, projectile_distance_m=projectile_distance),
            UNICON_TABLE2["projectile"][n]) for n in PROJECTILE_EVERY]
    if "mass" in groups:
        out += [Row("mass", f"{k} x{m:g}", xe.Perturbation(mass=m), UNICON_TABLE2["mass"][k]) for k, m in MASSES.items()]
    if "shape" in groups:
        out.append(Row("shape", f"{shapes} random shapes (seed {seed})", xe.Perturbation(shapes=shapes, shape_seed=seed)))
    return out


def row_groups(text: str) -> tuple[str, ...]:
    """`--rows`: a comma-separated subset of speed, projectile, mass, shape, in that order; ValueError
    naming `text` otherwise."""
    parts = tuple(p.strip() for p in text.split(",") if p.strip())
    bad = [p for p in parts if p not in GROUPS]
    if not parts or bad:
        raise ValueError(f"{text!r} must be a comma-separated list of {', '.join(GROUPS)}")
    return tuple(g for g in GROUPS if g in parts)


PROG = "morphmimic robustness"
EXECUTOR_ONLY = ("clips", "starts", "projectile_speed", "projectile_distance", "settings")
SHAPE_ONLY = ("episode_s",)
SHAPE_CONTROLLER_SHAPES = 20


@validated
@dataclass(kw_only=True)
class RobustnessOptions:
    checkpoint: str
    """Checkpoint dir, state.pt, run dir or learner/pretrained/<name>."""
    rows: Annotated[tuple[str, ...], harness.one_value(row_groups, "speed,projectile,mass,shape", ",".join)] = GROUPS
    """Groups of rows."""
    clips: Clips = ()
    """Executor: clip ids, files or folders of .npz clips (default: the clips it trained on)."""
    starts: int = 3
    """Executor: start frames per clip."""
    projectile_speed: float = PROJECTILE_SPEED_MPS
    """Executor: launch speed of the projectile, m/s."""
    projectile_distance: float = PROJECTILE_DISTANCE_M
    """Executor: horizontal distance from the root the projectile is launched from, m."""
    shapes: int | None = None
    """Shape controllers: random shapes (default 20); the executor: random shapes of its "shape" row (default 10)."""
    episode_s: float = 10.0
    """Shape controllers: episode length, s."""
    seed: int = SHAPE_SEED
    """Seed of the shape draws (shape controllers' episodes, the executor's "shape" row)."""
    workers: int = 1
    """Processes running episodes."""
    settings: Settings = ()
    out: str = ""
    """Output directory (default: <checkpoint dir>/robustness)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"starts": at_least(1), "projectile_speed": above(0),
                                          "projectile_distance": above(0), "shapes": at_least(1),
                                          "episode_s": above(0), "seed": SEED, "workers": at_least(1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def relative(perf: float | None, base: float | None) -> float | None:
    """perf / base, None when either is missing or the base is 0."""
    if perf is None or not base:
        return None
    return perf / base


# ---- the executor ----


def projectile_flight_steps(row: Row, control_hz: float) -> int:
    """Control steps a thrown ball needs to reach the root (straight line, at its launch speed)."""
    p = row.perturbation
    return int(math.ceil(p.projectile_distance_m / p.projectile_speed_mps * control_hz))


def projectile_problem(loaded: checkpoint.Loaded, clip: xe.EvalClip) -> str | None:
    """Why the projectile rows cannot run with this environment, or None: the character must
    start on the tracked frame in an environment that has the projectile body."""
    env = xe.make_eval_env(loaded, [clip], xe.Perturbation(projectile_every=1))
    env.reset(0, env.space.default_array, clip_id=clip.clip_id, start_s=0.0)
    off = float(np.linalg.norm(env.qpos[0:3] - env.scheduler.frame(0).qpos[0:3]))
    if off > 0.25:
        return (f"with the projectile balls in the scene the character starts {off:.1f} m from its tracked frame "
                "(a parked ball touches the character or the floor)")
    return None


def executor_rows(loaded: checkpoint.Loaded, clips: list[xe.EvalClip], starts: int, workers: int, rows: list[Row],
                  log=None) -> tuple[dict, list[dict]]:
    """(the unperturbed row, one result per row), the same (clip, start) episodes in each."""
    base_env = xe.make_eval_env(loaded, clips)
    durations = xe.clip_durations(base_env, clips)
    hz = loaded.cfg.task.control_hz

    def measure(name: str, pert: xe.Perturbation, progress=None) -> dict[str, Any]:
        t0 = time.monotonic()
        shapes = xe.eval_shapes(loaded.cfg.task, pert.shapes, pert.shape_seed) if pert.shapes else None
        records = xe.evaluate(loaded, clips, starts, workers, pert, progress=progress, durations=durations, shapes=shapes)
        s = xe.stats(records)
        out = {"row": name, "stats": s, "performance": s["performance"], "success_pct": s["success_pct"],
               "mean_return": s["mean_return"], "seconds": time.monotonic() - t0,
               "episodes": [{k: r[k] for k in ("clip_id", "start_s", "return", "planned_steps", "success", "shape_index")
                             if k in r} for r in records]}
        if shapes is not None:
            out["shapes"] = {"names": list(xe.shape_space(loaded.cfg.task).names), "seed": pert.shape_seed,
                             "params": shapes.tolist()}
        return out

    problem = projectile_problem(loaded, clips[0]) if any(r.group == "projectile" for r in rows) else None

    def skip(row: Row) -> str | None:
        if row.group != "projectile":
            return None
        if problem:
            return problem
        flight = projectile_flight_steps(row, hz)
        if row.perturbation.projectile_every * PROJECTILES < flight:
            return (f"{PROJECTILES} projectile balls: thrown every {row.perturbation.projectile_every} steps, each is thrown "
                    f"again before it arrives ({flight} steps of flight: {row.perturbation.projectile_distance_m:g} m at "
                    f"{row.perturbation.projectile_speed_mps:g} m/s), so nothing would hit")
        return None

    return _run_rows(rows, measure, skip, log)


# ---- shape controllers (Won & Lee walkers and swimmers) ----


class _MassScaled:
    """An `ImitateEnv` whose every character body is `factor` times heavier (masses and
    inertias). Applied after each reset, since a reset may switch to another cached shape's
    model; the previous episode's model gets its own masses back first, so a model the shape
    cache hands out again is never scaled twice. Masses change through `common.characters.mass`,
    which also recomputes what MuJoCo derives from them (the subtree masses the COM divides by)."""

    def __init__(self, env, factor: float):
        self._env, self._factor = env, factor
        self._scaled: tuple | None = None

    def __getattr__(self, name):
        return getattr(self._env, name)

    def reset(self, seed, params, *a, **k):
        if self._scaled is not None:
            m, mass, inertia = self._scaled
            set_body_mass(m, mass, inertia)
        out = self._env.reset(seed, params, *a, **k)
        m = self._env.model
        self._scaled = (m, m.body_mass.copy(), m.body_inertia.copy())
        scale_body_mass(m, self._scaled[1], self._scaled[2], self._factor)
        return out

    def step(self, action):
        return self._env.step(action)


_SHAPE: dict[str, Any] = {}


def _shape_task(cfg, episode_s: float, speed: float):
    task = harness.eval_task(cfg, episode_s)
    if speed != 1.0:
        lo, hi = task.imitate.speed_range
        task = dataclasses.replace(task, imitate=dataclasses.replace(task.imitate, speed_range=(min(lo, speed), max(hi, speed))))
    return task


def _init_shape(state_file: str, episode_s: float, pert: xe.Perturbation) -> None:
    torch.set_num_threads(1)
    loaded = checkpoint.load_trained(state_file)
    env = make_env(_shape_task(loaded.cfg.task, episode_s, pert.speed), seed=0)
    _SHAPE.update(env=_MassScaled(env, pert.mass) if pert.mass != 1.0 else env,
                  policy=checkpoint.make_policy(loaded, env.obs_dim, env.act_dim), pert=pert)


def _shape_work(job: tuple[int, np.ndarray, int]) -> dict[str, Any]:
    i, params, seed = job
    params = params.copy()
    env, pert = _SHAPE["env"], _SHAPE["pert"]
    if pert.speed != 1.0:
        params[list(env.space.names).index("speed")] = pert.speed
    r = episodes.run_episode(env, _SHAPE["policy"], params, seed)
    return {"index": i, "return": r["return"], "fell": r["fell"] or r["diverged"], "steps": r["steps"]}


def shape_rows(loaded: checkpoint.Loaded, shapes: int, episode_s: float, seed: int, workers: int, rows: list[Row],
               log=None) -> tuple[dict, list[dict]]:
    """(the unperturbed row, one result per row) for a shape controller on `shapes` random shapes."""
    space = task_space(harness.eval_task(loaded.cfg.task, episode_s))
    params = episodes.eval_shapes(space, shapes, seed)
    if "speed" in space.names:  # the unperturbed episodes play at normal speed; rows set their own
        params[:, list(space.names).index("speed")] = 1.0
    planned = max(1, int(round(episode_s * loaded.cfg.task.control_hz)))
    jobs = [(i, params[i], seed + i) for i in range(len(params))]

    def measure(name: str, pert: xe.Perturbation, progress=None) -> dict[str, Any]:
        t0 = time.monotonic()
        init = (str(loaded.path), episode_s, pert)
        res = harness.run_jobs(_init_shape, init, _shape_work, jobs, workers, progress)
        perf = float(np.mean([r["return"] / planned for r in res]))
        return {"row": name, "performance": perf, "success_pct": 100.0 * float(np.mean([not r["fell"] for r in res])),
                "mean_return": float(np.mean([r["return"] for r in res])), "seconds": time.monotonic() - t0,
                "episodes": [{"index": r["index"], "return": r["return"], "success": not r["fell"]} for r in res]}

    def skip(row: Row) -> str | None:
        if row.group == "projectile":
            return f"task {loaded.cfg.task.name!r} has no projectile body (the executor's robustness hook)"
        if row.group == "shape":
            return "a shape controller's episodes are already on random shapes (every row above is)"
        if row.group == "speed" and "speed" not in loaded.cfg.task.imitate.task_params:
            return ("trained without the 'speed' task parameter: a shape task plays its reference at another "
                    "speed only through that parameter, which is part of the observation, so this policy cannot take it")
        return None

    return _run_rows(rows, measure, skip, log)


def _run_rows(rows: list[Row], measure, skip, log=None) -> tuple[dict, list[dict]]:
    """(the unperturbed row, one result per row): `measure(name, perturbation, progress)` each row
    that `skip(row)` gives no reason for, each made relative to the unperturbed one and logged
    (`log`, default a line on stdout above the progress bar). The bar counts episodes over every
    row measured: each row runs the same episodes."""
    reasons = [skip(row) for row in rows]
    measured = 1 + sum(reason is None for reason in reasons)
    with Progress("[robustness]", measured, "episodes") as bar:
        say = log or bar.write

        def progress(k: int):
            # NOTE: a shape row runs its episodes on each shape: counted as one row's share of the bar
            return lambda done, total: bar.set(k * measured_total[0] + done * measured_total[0] // max(total, 1),
                                               measured * measured_total[0])

        measured_total = [1]

        def base_progress(done: int, total: int) -> None:
            measured_total[0] = total
            bar.set(done, measured * total)

        base = measure("unperturbed", xe.Perturbation(), base_progress)
        say(_line(base, base))
        out, k = [], 1
        for row, reason in zip(rows, reasons):
            res = {"group": row.group, "x": row.x, "paper": row.paper, "row": row.name}
            if reason:
                res["skipped"] = reason
            else:
                res.update(measure(row.name, row.perturbation, progress(k)))
                k += 1
            _finish(res, base)
            out.append(res)
            say(_line(res, base))
    return _finish(base, base), out


def _finish(res: dict, base: dict) -> dict:
    if "skipped" not in res:
        res["relative"] = relative(res["performance"], base["performance"])
        res["relative_return"] = relative(res["mean_return"], base["mean_return"])
    return res


_SAID: set[str] = set()


def _line(res: dict, base: dict) -> str:
    if "skipped" in res:
        said = res["skipped"] in _SAID
        _SAID.add(res["skipped"])
        return f"[robustness] {res['row']}: skipped ({'as above' if said else res['skipped']})"
    rel = relative(res["performance"], base["performance"])
    paper = res.get("paper")
    return (f"[robustness] {res['row']}: relative performance {'-' if rel is None else f'{100 * rel:.1f}%'}"
            f"{'' if not paper else f' (UniCon {paper[0]:g}%)'}, success {res['success_pct']:.1f}%, "
            f"performance {res['performance']:.3f} ({res['seconds']:.0f} s)")


def main(argv: list[str]) -> int:
    args = parse_options(RobustnessOptions, argv, prog=PROG, description=__doc__)
    loaded = checkpoint.load_trained(args.checkpoint)
    executor = registry.family_of(loaded.cfg.task.name, "robustness") == "executor"  # refuses a task it does not take
    given = harness.changed_flags(args, SHAPE_ONLY if executor else EXECUTOR_ONLY, {"settings": "--set"})
    if given:
        refuse(PROG, f"{', '.join(given)}: not options for task {loaded.cfg.task.name!r} "
                     f"({'executor' if executor else 'shape controller'} checkpoints take "
                     f"{'--clips, --starts, --projectile-speed, --projectile-distance, --set, --shapes and --seed (its shape row)' if executor else '--shapes, --episode-s, --seed'})")
    if executor and "shape" not in args.rows and (args.shapes is not None or args.seed != SHAPE_SEED):
        refuse(PROG, f"--shapes, --seed: the executor's shape row's options; --rows {','.join(args.rows)} has no shape row")
    if executor:
        try:
            loaded = xe.with_settings(loaded, list(args.settings))
        except ValueError as exc:
            refuse(PROG, str(exc))
    rows = rows_for(args.rows, args.projectile_speed, args.projectile_distance,
                    args.shapes or EXECUTOR_SHAPES, args.seed)
    out = Path(args.out) if args.out else loaded.path.parent / "robustness"
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    if executor:
        clips = select_clips(PROG, args.clips, loaded) if args.clips else xe.default_clips(loaded.cfg.task, ("train",))
        if not clips:
            refuse(PROG, f"--checkpoint {args.checkpoint}: it trained on no humanoid clip; name --clips")
        base, results = executor_rows(loaded, clips, args.starts, args.workers, rows)
        protocol = {"clips": [c.clip_id for c in clips], "starts": args.starts, "settings": list(args.settings), "projectile": {
            **robustness_report.projectile_spec(), "speed_mps": args.projectile_speed, "distance_m": args.projectile_distance}}
        if "shape" in args.rows:
            space = xe.shape_space(loaded.cfg.task)
            protocol["shape"] = {"shapes": args.shapes or EXECUTOR_SHAPES, "seed": args.seed,
                                 "parameterization": loaded.cfg.task.body.parameterization,
                                 "box": {n: [lo, hi] for n, lo, hi in zip(space.names, space.low, space.high)},
                                 "trained_on_shapes": loaded.cfg.task.body.vary_shape}
    else:
        shapes = args.shapes or SHAPE_CONTROLLER_SHAPES
        base, results = shape_rows(loaded, shapes, args.episode_s, args.seed, args.workers, rows)
        protocol = {"shapes": shapes, "episode_s": args.episode_s, "seed": args.seed}
    files = robustness_report.write(loaded, base, results, protocol, out, time.monotonic() - t0)
    print(f"[robustness] {loaded.name}: wrote {', '.join(Path(f).name for f in files)} to {out}")
    return 0

