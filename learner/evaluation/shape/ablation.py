"""`morphmimic ablation`: Won & Lee 2019's ablations (METHOD.md A, "Results to reproduce") as one
comparison table over several checkpoints, every one evaluated on the same shapes.

    morphmimic ablation --checkpoints runs/lower_biped runs/lower_biped-uniform \\
        runs/lower_biped-nonorm runs/lower_biped-fixedshape --out ablation/lower_biped

Rows: with vs without reward normalization; adaptive (k > 0) vs uniform (k = 0) sampling,
compared by the uniformity of the measured return map (min/mean over the grid of two shape
parameters; beside it two measures that do not rest on one cell, `spread`) and the fall-down %
on the most extreme 10% of shapes; trained without shape
variation. Under the table, whether the paper's two effects reproduce (`effects`). Both fall
rules are in the table; `--fall-rule paper` also ends the episodes by the paper's. Each checkpoint is evaluated by `morphmimic evaluate` into `<out>/<run name>/`, or
`<run name>-<iteration>/` when several checkpoints of one run are compared (an existing
`results.json` there with the same protocol is reused); the table goes to `<out>/ablation.md`
and `<out>/ablation.json` and is printed.

Single checkpoints of one run swing by several points, so `--last N` takes each run directory's
newest N checkpoints as one arm: every checkpoint gets its row, each arm a row of its means, and
the effects are judged on the means, with each arm's range of fall-down rates beside them.

    morphmimic ablation --checkpoints runs/lb6-shank runs/lbabl-uniform runs/lbabl-nonorm --last 4 \
        --workers 2 --out learner/pretrained/lower_biped-20M/ablation

`morphmimic ablation` runs this when the first checkpoint is a shape controller's
(`learner/evaluation/registry.py`); on motion executor checkpoints the UniCon ablation table is
made instead (`learner/evaluation/executor/ablation.py`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, ClassVar

import numpy as np

from common.config_limits import Limit, at_least, check_limits, validated
from common.tasks.shape.env import character_preset
from learner.cli_options import parse_options, refuse, value_list
from learner.evaluation import harness
from learner.evaluation.shape import episodes, evaluate
from learner.evaluation.shape.evaluate import ShapeProtocol
from learner import checkpoint

PROG = "morphmimic ablation"


@validated
@dataclass(kw_only=True)
class AblationOptions(ShapeProtocol):
    checkpoints: Annotated[tuple[str, ...], value_list(str, "CHECKPOINT", nargs="+")]
    """Checkpoints or run directories to compare."""
    out: str = "ablation"
    """Output directory."""
    last: int = 1
    """Take each run directory's newest N checkpoints as one arm, judged on their means."""

    LIMITS: ClassVar[dict[str, Limit]] = {**ShapeProtocol.LIMITS, "last": at_least(1)}

    def validate(self) -> None:
        check_limits(self)


def describe(cfg) -> str:
    """What distinguishes a run in the ablation: sampling, normalization, shape variation."""
    t = cfg.task
    parts = ["adaptive k=%g" % cfg.sampler.k if cfg.sampler.k > 0 else "uniform (k=0)"]
    parts.append("reward norm" if t.imitate.reward_normalization else "no reward norm")
    if not t.body.vary_shape:
        parts = ["base shape only"] + parts[1:]
    elif t.body.shape_box_scale != 1.0:
        parts.append(f"shape box x{t.body.shape_box_scale:g}")
    return ", ".join(parts)


def _still_valid(res_file: Path, loaded: checkpoint.Loaded, args: AblationOptions) -> bool:
    """Whether an earlier results.json measured this checkpoint by this protocol on the body this
    tree builds; a file that is not such a results.json is measured again, not trusted."""
    imitate = loaded.cfg.task.imitate
    try:
        old = json.loads(res_file.read_text())
        meta = old["meta"]
        return bool(meta["checkpoint"] == str(loaded.path) and meta["seed"] == args.seed
                    and meta["episode_s"] == args.episode_s and old["summary"]["shapes"] == args.shapes
                    and meta.get("fall_rule", "task") == args.fall_rule
                    and meta.get("root_height", imitate.retarget.root_height) == imitate.retarget.root_height
                    and meta.get("clearance_m", imitate.retarget.body_clearance_m) == imitate.retarget.body_clearance_m
                    and meta.get("body_digest") == episodes.body_digest(character_preset(loaded.cfg.task)))
    except (ValueError, KeyError, TypeError, AttributeError):  # not JSON, or not an evaluation's results
        return False


def evaluate_one(ckpt: str, out: Path, args: AblationOptions, folder: str = "") -> dict:
    """Evaluate one checkpoint into `<out>/<folder>` (default: its run name)."""
    loaded = checkpoint.load_trained(ckpt)
    target = out / (folder or loaded.name)
    res_file = target / "results.json"
    if res_file.exists() and _still_valid(res_file, loaded, args):
        print(f"[ablation] reusing {res_file}", flush=True)
        return {"loaded": loaded, **json.loads(res_file.read_text())}
    argv = ["--checkpoint", ckpt, "--shapes", str(args.shapes), "--seed", str(args.seed), "--episode-s",
            str(args.episode_s), "--workers", str(args.workers), "--out", str(target), "--no-render",
            "--fall-rule", args.fall_rule]
    if args.map_params:
        argv += ["--map-params", *args.map_params]
    evaluate.main(argv)
    return {"loaded": loaded, **json.loads(res_file.read_text())}


def arms_of(paths: list[str], last: int) -> list[list[str]]:
    """Each path's checkpoints as one arm: a run directory's newest `last` (all it has when it has
    fewer), a checkpoint folder or file itself alone; SystemExit naming a path that holds none."""

    arms = []
    for path in paths:
        found = checkpoint.list_checkpoints(Path(path) / "ckpt")
        arms.append([str(c) for c in found[-last:]] if found else [str(checkpoint.resolve(path).parent)])
    return arms


MEAN_KEYS = ("task_achievement", "fall_down_pct", "fall_down_pct_paper_rule", "fall_down_pct_extreme10",
             "mean_seconds", "return_map_uniformity", "mean_return")
"""The summary figures an arm of several checkpoints reports as its mean."""


def mean_row(rows: list[dict]) -> dict:
    """One arm's checkpoints (rows of one run) as one row: the mean of each `MEAN_KEYS` figure
    that every row has, the mean of their `spread`, and each checkpoint's fall-down % (by the
    paper's rule where measured) under `checkpoint_falls`."""
    numbers = {k: [_number(r["summary"].get(k)) for r in rows] for k in MEAN_KEYS}
    summary = {k: float(np.mean(v)) for k, v in numbers.items() if np.all(np.isfinite(v))}
    spreads = np.array([spread(r) for r in rows], dtype=np.float64)
    first, last = rows[0]["meta"], rows[-1]["meta"]
    name = f"{first['name']}, mean of {len(rows)} (iterations {first['iteration']}-{last['iteration']})"
    return {"loaded": rows[0]["loaded"], "summary": summary, "spread": tuple(spreads.mean(axis=0)),
            "meta": {**last, "name": name},
            "checkpoint_falls": [_number(r["summary"].get("fall_down_pct_paper_rule", r["summary"].get("fall_down_pct")))
                                 for r in rows]}


def _number(x: object) -> float:
    """`x` as a float, NaN unless it is a real number (a results.json written elsewhere may hold anything)."""
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else float("nan")


def _folders(checkpoints: list[str]) -> list[str]:
    """Output folder per checkpoint: its run name, or `<run name>-<iteration>` when several
    checkpoints of one run are compared (so one does not overwrite another's results)."""
    loaded = [checkpoint.load_trained(c) for c in checkpoints]
    names = [x.name for x in loaded]
    return [f"{x.name}-{int(x.state['iteration'])}" if names.count(x.name) > 1 else x.name for x in loaded]


def spread(row: dict) -> tuple[float, float]:
    """Two measures of how evenly the return is spread that do not rest on one map cell (the
    map's min/mean does: a cell holds about 8 of 300 shapes): the 10th percentile of the
    per-shape returns over their mean (1 = even), and the coefficient of variation of the map's
    cells (0 = even). NaN where the results lack them."""
    if "spread" in row:  # an arm's mean row carries its checkpoints' mean
        return row["spread"]
    returns = np.array([x["return"] for x in row.get("shapes", [])], dtype=np.float64)
    cells = np.array(row["summary"].get("return_map", []), dtype=np.float64).reshape(-1)
    cells = cells[cells >= 0]  # -1 marks an empty cell
    p10 = float(np.percentile(returns, 10) / returns.mean()) if returns.size and returns.mean() > 0 else float("nan")
    cv = float(cells.std() / cells.mean()) if cells.size and cells.mean() > 0 else float("nan")
    return p10, cv


def table(rows: list[dict]) -> str:
    head = ("| run | training | env steps | task achievement | fall-down % | fall-down %, paper's rule "
            "| fall-down % (extreme 10%) | mean time up (s) | return map min/mean | return p10/mean (shapes) "
            "| return map cell CV | mean return |")
    lines = [head, "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        s, m = r["summary"], r["meta"]
        p10, cv = spread(r)

        def fig(key: str, digits: int) -> str:
            return "-" if s.get(key) is None else format(s[key], f".{digits}f")

        name = f"**`{m['name']}`**" if "checkpoint_falls" in r else f"`{m['name']}`"
        lines.append(f"| {name} | {describe(r['loaded'].cfg)} | {m['env_steps']:,d} | {fig('task_achievement', 1)} "
                     f"| {fig('fall_down_pct', 1)} | {fig('fall_down_pct_paper_rule', 1)} "
                     f"| {fig('fall_down_pct_extreme10', 1)} | {fig('mean_seconds', 1)} "
                     f"| {fig('return_map_uniformity', 2)} | {p10:.2f} | {cv:.2f} "
                     f"| {fig('mean_return', 1)} |")
    return "\n".join(lines)


FALL_MARGIN_PCT = 3.0
"""Fall-down differences (points) within this are called inconclusive: one machine's figures
move by about 1.5 points on another, neighbouring checkpoints by about 5
(docs/shape-controllers.md)."""

UNIFORMITY_MARGIN = 0.05
"""Return-map min/mean differences within this are called inconclusive."""


def _arm(rows: list[dict], task: str, k_positive: bool, normalized: bool) -> dict | None:
    """The first row of `task` trained on varying shapes with adaptive (`k_positive`) or uniform
    sampling and with or without reward normalization; None if the comparison lacks it."""
    for r in rows:
        cfg = r["loaded"].cfg
        if (cfg.task.name == task and cfg.task.body.vary_shape and (cfg.sampler.k > 0) == k_positive
                and cfg.task.imitate.reward_normalization == normalized):
            return r
    return None


def _verdict(better: float, worse: float, margin: float) -> str:
    """"reproduces" if `better` beats `worse` by more than `margin` (smaller is better: pass
    negated values for larger-is-better), "does not reproduce" if it is worse by more,
    "inconclusive" between, "not measurable" if either is not a number."""
    if not (np.isfinite(better) and np.isfinite(worse)):
        return "not measurable"
    if better < worse - margin:
        return "reproduces"
    return "does not reproduce" if better > worse + margin else f"inconclusive (within {margin:g})"


def _ranges(a: dict, b: dict) -> str:
    """"; checkpoints a0-a1% against b0-b1%[, apart]" when both rows are means of several
    checkpoints ("apart": every checkpoint of one arm on the same side of every one of the other's),
    else ""."""
    if "checkpoint_falls" not in a or "checkpoint_falls" not in b:
        return ""
    fa, fb = a["checkpoint_falls"], b["checkpoint_falls"]
    apart = max(fa) < min(fb) or max(fb) < min(fa)
    return (f"; its {len(fa)} and {len(fb)} checkpoints: {min(fa):.1f}-{max(fa):.1f}% against {min(fb):.1f}-{max(fb):.1f}%"
            f"{', apart' if apart else ', overlapping'}")


def _achievement(with_norm: dict, without: dict) -> str:
    """", task achievement N% higher (lower) with it": normalization's effect on task achievement
    relative to the arm without, which compares on any scale (the paper's own figures: 369.5
    against 218.9 on the lower biped, 427.5 against 338.2 on the quadruped); "" if either is
    missing or the arm without has none."""
    a, b = (x["summary"].get("task_achievement") for x in (with_norm, without))
    numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in (a, b))
    if not numbers or not b > 0:  # results.json files written elsewhere may lack the figure or hold anything
        return ""
    change = 100.0 * (a / b - 1.0)
    return f", task achievement {abs(change):.0f}% {'higher' if change >= 0 else 'lower'} with it ({a:.1f} against {b:.1f})"


def effects(rows: list[dict]) -> list[str]:
    """Whether Won & Lee 2019's two ablation effects (METHOD.md A, "Results to reproduce")
    reproduce among `rows`, per task: reward normalization lowers the fall-down rate (the
    adaptive arm with normalization against the one without, by the paper's fall rule, the
    rule of its figures), and adaptive sampling evens out the return map (min/mean above
    uniform sampling's) and lets the most extreme 10% of shapes fall less. Differences
    inside `FALL_MARGIN_PCT` or `UNIFORMITY_MARGIN` are inconclusive. One line each; a
    comparison whose arms are missing says so."""
    lines = []
    for task in sorted({r["loaded"].cfg.task.name for r in rows}):
        base, nonorm, uniform = _arm(rows, task, True, True), _arm(rows, task, True, False), _arm(rows, task, False, True)
        if base and nonorm:
            fall = [x["summary"].get("fall_down_pct_paper_rule", x["summary"]["fall_down_pct"]) for x in (base, nonorm)]
            own = [x["summary"]["fall_down_pct"] for x in (base, nonorm)]
            by_task = ("" if base.get("meta", {}).get("fall_rule") == "paper"  # the paper's rule ended the episodes
                       else f"; by the task's rule {own[0]:.1f}% and {own[1]:.1f}%")
            lines.append(f"- {task}, reward normalization lowers falls: **{_verdict(fall[0], fall[1], FALL_MARGIN_PCT)}** "
                         f"(by the paper's rule {fall[0]:.1f}% with it, {fall[1]:.1f}% without{by_task}{_ranges(base, nonorm)}"
                         f"{_achievement(base, nonorm)}; "
                         "the paper: 20.7% against 54.1% on the lower biped, 9.3% against 11.1% on the quadruped, task "
                         "achievement 69% and 26% higher with it).")
        else:
            lines.append(f"- {task}, reward normalization: not compared (an adaptive arm with and one without "
                         "normalization are needed).")
        if base and uniform:
            a, b = base["summary"]["return_map_uniformity"], uniform["summary"]["return_map_uniformity"]
            ea, eb = base["summary"]["fall_down_pct_extreme10"], uniform["summary"]["fall_down_pct_extreme10"]
            verdict = _verdict(-a, -b, UNIFORMITY_MARGIN)
            (pa, ca), (pb, cb) = spread(base), spread(uniform)
            if verdict == "reproduces" and (pa < pb - UNIFORMITY_MARGIN or ca > cb + UNIFORMITY_MARGIN):
                verdict = "reproduces by the worst cell only"
            lines.append(f"- {task}, adaptive sampling evens out the return map: **{verdict}** "
                         f"(min/mean {a:.2f} adaptive, {b:.2f} uniform; per-shape return p10/mean {pa:.2f} and "
                         f"{pb:.2f}, map cell CV {ca:.2f} and {cb:.2f}; the paper: a markedly more uniform map).")
            lines.append(f"- {task}, adaptive sampling lets extreme shapes fall less: **{_verdict(ea, eb, FALL_MARGIN_PCT)}** "
                         f"(the most extreme 10% of shapes fall {ea:.1f}% adaptive, {eb:.1f}% uniform, by the "
                         f"{'paper' if base.get('meta', {}).get('fall_rule') == 'paper' else 'task'}'s rule; the paper: "
                         "extreme shapes fall far less).")
        else:
            lines.append(f"- {task}, adaptive sampling: not compared (an adaptive and a uniform arm, both normalized, "
                         "are needed).")
    return lines


def main(argv: list[str]) -> int:
    args = parse_options(AblationOptions, argv, prog=PROG, description=__doc__)
    executors = [c for c in args.checkpoints if checkpoint.load_trained(c).cfg.task.name == "executor"]
    if executors:
        refuse(PROG, f"--checkpoints {' '.join(executors)}: executor checkpoints; compare them with executor checkpoints only")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    arms = arms_of(args.checkpoints, args.last)
    flat = [c for arm in arms for c in arm]
    evaluated = iter([evaluate_one(c, out, args, folder) for c, folder in zip(flat, _folders(flat))])
    by_arm = [[next(evaluated) for _ in arm] for arm in arms]
    judged = [arm[0] if len(arm) == 1 else mean_row(arm) for arm in by_arm]  # an arm of several: its mean
    means = [row for arm, row in zip(by_arm, judged) if len(arm) > 1]
    rows = [r if len(arm) == 1 else {**r, "meta": {**r["meta"], "name": f"{r['meta']['name']} @ {r['meta']['iteration']}"}}
            for arm in by_arm for r in arm] + means
    tasks = {r["loaded"].cfg.task.name for r in rows}
    text = "\n".join([
        f"# Ablations ({', '.join(sorted(tasks))})", "",
        f"{args.shapes} random shapes (seed {args.seed}), {args.episode_s:g} s episodes, mean action, episodes ended by "
        f"{'the paper' if args.fall_rule == 'paper' else 'the task'}'s fall rule; the return map "
        "is binned over two shape parameters (min/mean: 1 = uniform); return p10/mean is the 10th percentile of the "
        "per-shape returns over their mean, cell CV the coefficient of variation of the map's cells (0 = uniform).", "",
        table(rows), "",
        "The paper's two effects, here" + (" (judged on each arm's mean over its checkpoints, the bold rows):" if means else ":"),
        "", *effects(judged), "",
        "Paper (Won & Lee 2019): fall-down 20.7% for the lower-body biped with reward normalization, 54.1% without; "
        "quadruped 9.3% with, 11.1% without; adaptive sampling makes the map markedly more uniform and extreme shapes "
        "fall far less. Task achievement is this project's own scale, not comparable with the paper's; every "
        "difference from the paper's protocol is listed in docs/shape-controllers.md.", "",
    ])
    harness.write_ablation(out, text, [{"name": r["meta"]["name"], "training": describe(r["loaded"].cfg), "meta": r["meta"],
                                          "summary": r["summary"],
                                          **({"checkpoint_falls": r["checkpoint_falls"]} if "checkpoint_falls" in r else {})}
                                         for r in rows])
    return 0

