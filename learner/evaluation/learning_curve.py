"""The learning curve of a run: every checkpoint evaluated the same
way, against environment steps and wall time. A shape controller's run: fall-down % and task
achievement on the same random shapes (a swimmer's also its speed error and time upright). A
motion executor's run: UniCon's success % per split (train, held-out test), as `morphmimic
evaluate` measures it (`executor/curve.py`). A reach run: success % within the radius and the
fingertip's final distance on the same targets (`reach/curve.py`).

    morphmimic learning-curve --ckpt-dir runs/history/lower_biped/ckpt --shapes 100 --episode-s 10
    morphmimic learning-curve --ckpt-dir runs/executor-pd-arm/ckpt --starts 10 --every 10 --workers 2
    morphmimic learning-curve --ckpt-dir runs/reach/ckpt --targets 100

Wall time of a checkpoint: the training seconds it records (summed over every session of a
resumed run, so pauses between sessions do not count). A checkpoint that does not record it
falls back to the file's modification time minus `--start` (default: the modification
time of the run's `config.json`, written when training starts; pass the run directory with
`--run-dir`). Writes `curve.json` (after every checkpoint) and `curve.png` into `--out` and
prints where the run first reached `--target`. Rows of an earlier `curve.json` in `--out` made
the same way (shapes, episode length, seed and box; an executor's clips and starts) are reused,
so a growing run is evaluated only on its new checkpoints, and kept when their checkpoints are
gone (a run keeps only its newest `keep_checkpoints`): the curve is the run's history. An
earlier curve made with other settings is refused, not overwritten.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from typing import ClassVar
from pathlib import Path

import numpy as np  # noqa: E402

from learner import checkpoint

from common.config_limits import SEED, Limit, above, at_least, between, check_limits, validated  # noqa: E402
from common.tasks.registry import make_env
from learner.cli_options import parse_options, refuse  # noqa: E402
from learner.evaluation import harness, registry  # noqa: E402
from learner.evaluation.shape import episodes

from learner.evaluation.executor import curve as executor_curve
from learner.evaluation.reach import curve as reach_curve

PROG = "morphmimic learning-curve"


@validated
@dataclass
class CurveOptions:
    ckpt_dir: str
    """Directory of <iteration>/state.pt checkpoints."""
    run_dir: str = ""
    """The run directory (its config.json time is the start)."""
    start: float = 0.0
    """Training start, Unix time in seconds (overrides --run-dir; 0: not given)."""
    shapes: int | None = None
    """Shape controllers: random shapes (default 100)."""
    episode_s: float | None = None
    """Shape controllers and reach: episode length, s (default 10; reach: the checkpoint's own)."""
    seed: int | None = None
    """Shape controllers and reach: the shapes' or targets' seed (default 2019)."""
    box_scale: float | None = None
    """Shape controllers: shapes from the box shrunk toward the base shape (a curriculum's progress;
    default 1: the whole box)."""
    starts: int | None = None
    """Executor: start frames per clip, as `morphmimic evaluate --starts` (default 10)."""
    targets: int | None = None
    """Reach: random targets (default 50)."""
    every: int = 1
    """Evaluate every n-th checkpoint (the last always)."""
    workers: int = 1
    """Processes running episodes."""
    target: float | None = None
    """Report reaching this: fall-down % at most (shape controllers, default 20), train success %
    at least (executor, default 90) or success % at least (reach, default 90)."""
    out: str = ""
    """Output directory (default: <ckpt-dir>/../curve)."""

    LIMITS: ClassVar[dict[str, Limit]] = {
        "start": at_least(0.0, integer=False), "shapes": at_least(1), "episode_s": above(0.0),
        "seed": SEED, "box_scale": between(0.0, 1.0, lo_open=True),
        "starts": at_least(1), "targets": at_least(1), "every": at_least(1), "workers": at_least(1), "target": between(0.0, 100.0)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(CurveOptions, argv, prog=PROG, description=__doc__)
    ckpts = checkpoint.list_checkpoints(Path(args.ckpt_dir))
    if not ckpts:
        raise SystemExit(f"--ckpt-dir {args.ckpt_dir}: no checkpoints")
    newest = checkpoint.load_trained(ckpts[-1])  # the run's task decides which curve
    family = registry.family_of(newest.cfg.task.name, "learning-curve")  # refuses a task the registry does not list
    executor, reach = family == "executor", family == "reach"
    given = {"--shapes": args.shapes, "--episode-s": args.episode_s, "--seed": args.seed, "--box-scale": args.box_scale,
             "--starts": args.starts, "--targets": args.targets}
    misplaced = [flag for flag, value in given.items() if value is not None and flag not in CURVE_FLAGS[family]]
    if misplaced:
        owners = [kind for kind, flags in CURVE_FLAGS.items() if misplaced[0] in flags]
        refuse(PROG, f"{', '.join(misplaced)}: {OWNER_TEXT[owners[0]]}{''.join(' or ' + CURVE_TEXT[o] for o in owners[1:])}; "
                     f"{newest.name} is {'an' if executor else 'a'} {newest.cfg.task.name} run (its curve takes "
                     f"{', '.join(CURVE_FLAGS[family])})")
    if executor:
        args = dataclasses.replace(args, starts=args.starts or 10,
                                   target=executor_curve.DEFAULT_TARGET if args.target is None else args.target)
        proto = executor_curve.protocol(newest, args.starts)
    elif reach:
        args = dataclasses.replace(args, target=reach_curve.DEFAULT_TARGET if args.target is None else args.target)
        proto = reach_curve.protocol(args.targets or reach_curve.DEFAULT_TARGETS,
                                     args.episode_s or newest.cfg.task.episode_s, 2019 if args.seed is None else args.seed)
    else:
        args = dataclasses.replace(args, shapes=args.shapes or 100, episode_s=args.episode_s or 10.0,
                                   seed=2019 if args.seed is None else args.seed,
                                   box_scale=1.0 if args.box_scale is None else args.box_scale,
                                   target=20.0 if args.target is None else args.target)
        proto = {k: getattr(args, k) for k in PROTOCOL}
    ckpts = every_nth(ckpts, args.every)
    start = args.start or (os.path.getmtime(Path(args.run_dir) / "config.json") if args.run_dir else 0.0)
    out = Path(args.out) if args.out else Path(args.ckpt_dir).parent / "curve"
    out.mkdir(parents=True, exist_ok=True)
    done, stale = _earlier_rows(out / "curve.json", proto, family=family)
    rows = dict(done)
    for it, row in stale.items():  # kept unless its checkpoint is measured again below
        rows[it] = {**row, "fall_down_pct_extreme10": None}
    header = proto if executor or reach else {**proto, "extreme": EXTREME}

    fallback_wall = _wall_from_file_times(checkpoint.list_checkpoints(Path(args.ckpt_dir)), start)
    for c in ckpts:
        if int(c.name) in done:  # checkpoint directories are named by iteration: skip without loading
            continue
        loaded = checkpoint.load_trained(c)
        if loaded.cfg.task.name != newest.cfg.task.name:
            raise SystemExit(f"{loaded.path}: task {loaded.cfg.task.name!r}, but the newest checkpoint in --ckpt-dir "
                             f"is {newest.cfg.task.name!r}: one curve is one run")
        if executor and executor_curve.protocol(loaded, args.starts)["clips"] != proto["clips"]:
            raise SystemExit(f"{loaded.path}: its config evaluates other clips than the newest checkpoint's "
                             "(the run changed its clip set): curve the two parts into separate --out folders")
        wall = float(loaded.state.get("train_seconds", float("nan")))
        if not np.isfinite(wall):
            wall = fallback_wall.get(c, float("nan"))
        wall = wall if np.isfinite(wall) else None  # JSON null: unknown
        figures = (executor_curve.measure(loaded, args.starts, args.workers) if executor else
                   reach_curve.measure(loaded, proto) if reach else _shape_figures(loaded, args))
        row = {"iteration": int(loaded.state["iteration"]), "env_steps": int(loaded.state["env_steps"]), "wall_s": wall, **figures}
        rows[row["iteration"]] = row
        text = executor_curve.line(row) if executor else reach_curve.line(row) if reach else _shape_line(row)
        print(f"[curve] it {row['iteration']:5d} steps {row['env_steps']:>10,d} wall {_minutes(wall)} min | {text}", flush=True)
        _write(out / "curve.json", header, rows)  # after every row: an interrupted curve keeps what it measured
    _write(out / "curve.json", header, rows)
    ordered = [rows[i] for i in sorted(rows)]
    if executor:
        executor_curve.plot(ordered, out / "curve.png", args.target, args.starts)
        print(f"[curve] {executor_curve.reached(ordered, args.target)}")
        return 0
    if reach:
        reach_curve.plot(ordered, out / "curve.png", args.target, proto)
        print(f"[curve] {reach_curve.reached(ordered, args.target)}")
        return 0
    _plot(ordered, out / "curve.png", args)
    hit = next((r for r in ordered if r["fall_down_pct"] <= args.target), None)
    if hit:
        print(f"[curve] reached {args.target:g}% fall-down at {hit['env_steps']:,d} env steps, {_minutes(hit['wall_s'])} min")
    else:
        best = min(ordered, key=lambda r: r["fall_down_pct"])
        print(f"[curve] never reached {args.target:g}%: best {best['fall_down_pct']:.1f}% at {best['env_steps']:,d} steps")
    return 0


def _shape_line(row: dict) -> str:
    """A shape controller's console line of one row; a swimmer's with its speed error and time upright."""
    text = f"fall-down {row['fall_down_pct']:5.1f}% task {row['task_achievement']:6.1f} length {row['mean_seconds']:5.2f} s"
    if row.get("swim_upright_pct") is not None:
        error = row.get("swim_speed_error_pct")
        text += f" swim speed error {'-' if error is None else f'{error:.1f}'}% upright {row['swim_upright_pct']:.1f}%"
    return text


def _shape_figures(loaded: checkpoint.Loaded, args: CurveOptions) -> dict:
    """A shape controller's figures on the curve's random shapes (`episodes.summarize`)."""
    env = make_env(harness.eval_task(loaded.cfg.task, args.episode_s, args.box_scale), seed=0)
    shapes = episodes.eval_shapes(env.space, args.shapes, args.seed)
    res = episodes.evaluate(loaded, shapes, args.episode_s, args.seed, args.workers, box_scale=args.box_scale)
    return episodes.summarize(res, env.space, getattr(env, "n_shape", env.space.dim))


def _write(path: Path, header: dict, rows: dict[int, dict]) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({**header, "rows": [rows[i] for i in sorted(rows)]}, indent=1) + "\n")
    os.replace(tmp, path)


def _wall_from_file_times(ckpts: list[Path], start: float) -> dict[Path, float]:
    """Training seconds at each checkpoint from file modification times, for checkpoints that
    do not record them (an estimate; a checkpoint's own record is exact). The gaps between
    consecutive checkpoints count, except that a gap over 3x the run's median seconds per
    iteration times the iterations between them (the pause between two sessions of a resumed
    run) counts at the median rate, and so does a negative gap (a checkpoint copied or restored
    later than the ones after it: its file time says nothing about training). The first checkpoint
    counts from `start` when that is earlier (a resumed run rewrites config.json), else at the
    median rate."""
    if len(ckpts) < 2:
        return {}
    times = np.array([os.path.getmtime(c / checkpoint.FILE) for c in ckpts])
    iters = np.array([int(c.name) for c in ckpts], dtype=float)
    gaps, steps = np.diff(times), np.maximum(np.diff(iters), 1.0)
    forward = gaps > 0
    if not forward.any():
        return {}
    per_iteration = float(np.median(gaps[forward] / steps[forward]))
    first = times[0] - start if start and 0 < times[0] - start else per_iteration * iters[0]
    expected = per_iteration * steps
    wall = np.concatenate([[first], np.where(~forward | (gaps > 3.0 * expected), expected, gaps)]).cumsum()
    return dict(zip(ckpts, wall.tolist()))


def _minutes(seconds: float | None) -> str:
    return "     ?" if seconds is None or not np.isfinite(seconds) else f"{seconds / 60:6.1f}"


def every_nth(ckpts: list[Path], n: int) -> list[Path]:
    """Every n-th checkpoint (and the last), chosen on the iteration grid rather than by list
    position: the first checkpoint in each span of n x (the median iteration gap), so the choice
    stays the same when the run deletes its oldest checkpoints and earlier rows stay reusable."""
    if n == 1:  # every checkpoint, also one saved off the grid (at a stop)
        return list(ckpts)
    its = np.array([int(c.name) for c in ckpts])
    gap = float(np.median(np.diff(its))) if len(its) > 1 else 1.0
    bucket = (its // max(1.0, n * gap)).astype(np.int64)
    return [c for i, c in enumerate(ckpts) if i == 0 or bucket[i] != bucket[i - 1] or i == len(ckpts) - 1]


CURVE_FLAGS = {"shape": ("--shapes", "--episode-s", "--seed", "--box-scale"), "executor": ("--starts",),
               "reach": ("--targets", "--episode-s", "--seed")}
"""The options each family's curve takes (the others are refused for its runs)."""
OWNER_TEXT = {"shape": "options of a shape controller's curve", "executor": "an option of an executor's curve",
              "reach": "options of a reach curve"}
CURVE_TEXT = {"shape": "a shape controller's curve", "executor": "an executor's curve", "reach": "a reach curve"}

# Version of the extreme-10% column: "base" since it ranks shapes by their distance from the base
# shape (`episodes.extremeness`); curves written before then ranked them from the box centre.
EXTREME = "base"
PROTOCOL = ("shapes", "episode_s", "seed", "box_scale")


def _earlier_rows(path: Path, proto: dict, family: str = "shape") -> tuple[dict[int, dict], dict[int, dict]]:
    """Rows of an earlier curve.json in `--out`, iteration -> row: (current, stale). `proto`: the
    fields this call's rows depend on (the shapes, episode length, seed and box; for an executor
    the task, clips and starts; for reach the task, targets, episode length, seed and radius). A file made with others is refused rather than overwritten: its
    rows may be the only record of checkpoints the run has since deleted, and so is one whose rows
    lack or mistype a figure the curve reads (`_row_problem`). Shape curves (`family` "shape"): rows measured before the extreme-10% ranking changed are stale: their checkpoints
    are measured again, and rows whose checkpoints are gone keep their fall-down % with no
    extreme-10% figure."""
    if not path.exists():
        return {}, {}
    try:
        earlier = json.loads(path.read_text())
        earlier = {"box_scale": 1.0, **earlier} if "shapes" in earlier else earlier  # before --box-scale: the whole box
        rows = {int(r["iteration"]): r for r in earlier["rows"]}
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise SystemExit(f"{path}: unreadable curve ({exc}); move it away or choose another --out") from None
    differ = {k: (earlier.get(k), b) for k, b in proto.items() if earlier.get(k) != b}
    if differ:
        raise SystemExit(f"{path} was made with " + ", ".join(f"{k} {_short(a)}" for k, (a, _) in differ.items())
                         + "; this call asks for " + ", ".join(f"{k} {_short(b)}" for k, (_, b) in differ.items())
                         + ": choose another --out (its rows are kept)")
    for row in rows.values():
        problem = _row_problem(row, family)
        if problem:
            raise SystemExit(f"{path}: row of iteration {row.get('iteration')!r}: {problem}; move the file away or "
                             "choose another --out")
    return (rows, {}) if family != "shape" or earlier.get("extreme") == EXTREME else ({}, rows)


def _row_problem(row, family: str) -> str:
    """What is wrong with one row of a curve.json, or "" (each field the curve reads, by type)."""
    if not isinstance(row, dict):
        return f"{type(row).__name__}, not an object"
    for key in ("iteration", "env_steps"):
        if not isinstance(row.get(key), int) or isinstance(row.get(key), bool) or not 0 <= row[key] <= 2**53:
            return f"{key} = {_short(row.get(key))}; allowed: an integer in [0, 2^53]"
    if not executor_curve.is_figure(row.get("wall_s"), none_ok=True):
        return f"wall_s = {row.get('wall_s')!r}; allowed: seconds or null"
    if family == "executor":
        return executor_curve.row_problem(row)
    if family == "reach":
        return reach_curve.row_problem(row)
    if not executor_curve.is_figure(row.get("fall_down_pct")):
        return f"fall_down_pct = {row.get('fall_down_pct')!r}; allowed: a number"
    if not executor_curve.is_figure(row.get("fall_down_pct_extreme10"), none_ok=True):
        return f"fall_down_pct_extreme10 = {row.get('fall_down_pct_extreme10')!r}; allowed: a number or null"
    return ""


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _plot(rows: list[dict], path: Path, args) -> None:
    import matplotlib  # lazy: heavy (matplotlib), only when plotting

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: heavy (matplotlib), only when plotting

    steps = np.array([r["env_steps"] for r in rows]) / 1e6
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    ax.plot(steps, [r["fall_down_pct"] for r in rows], "o-", label="fall-down %")
    extreme = [np.nan if r.get("fall_down_pct_extreme10") is None else r["fall_down_pct_extreme10"] for r in rows]
    if np.isfinite(extreme).any():  # curves kept from before the ranking changed have none
        ax.plot(steps, extreme, "s--", label="fall-down % (extreme 10%, from the base shape)")
    ax.axhline(args.target, color="gray", lw=0.8, ls=":")
    ax.set_xlabel("environment steps (M)")
    ax.set_ylabel("%")
    ax.set_ylim(0, 100)
    box = "" if args.box_scale == 1.0 else f" (box x{args.box_scale:g})"
    ax.set_title(f"{args.shapes} random shapes{box}, {args.episode_s:g} s episodes", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
