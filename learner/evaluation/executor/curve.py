"""The learning curve of a motion executor run: UniCon's success rate per split at each
checkpoint, the rows and plot `learning_curve` writes for an executor's checkpoints.

Each checkpoint runs the episodes `morphmimic evaluate` runs (`executor_eval.evaluate`: every
clip of the run's config by split, `--starts` start frames each, on the tracked frame, mean
action), so a row equals that command's figures for that checkpoint. Success is UniCon 2020's
per-term criterion (METHOD.md B, the constrained objective: tracked to the clip's end with no
reward term below alpha); pose success the same on the four pose terms; PHC success the mean
body-position error never above 0.5 m.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from learner import checkpoint

# The per-split figures a row keeps (executor_eval.stats keys).

from learner.evaluation.executor import evaluate as xe
FIELDS = ("success_pct", "pose_success_pct", "phc_success_pct", "mpjpe_mm", "tracked_pct")
DEFAULT_TARGET = 90.0  # the goal: 90% of the train starts tracked to the end


def protocol(loaded: checkpoint.Loaded, starts: int) -> dict[str, Any]:
    """What a row of this curve depends on besides the checkpoint: the clips and the starts (the
    fields of curve.json that must match for its rows to be reused, `learning_curve._earlier_rows`)."""
    return {"task": "executor", "starts": starts, "clips": [c.clip_id for c in xe.default_clips(loaded.cfg.task)]}


def measure(loaded: checkpoint.Loaded, starts: int, workers: int) -> dict[str, Any]:
    """One checkpoint's figures: per split (train, test, ...) and overall, `FIELDS` each."""
    clips = xe.default_clips(loaded.cfg.task)
    summary = xe.summarize(xe.evaluate(loaded, clips, starts, workers), clips)
    keep = lambda s: {k: s.get(k) for k in FIELDS}  # noqa: E731
    return {"splits": {name: keep(s) for name, s in summary["splits"].items()}, "overall": keep(summary["overall"])}


def is_figure(value, none_ok: bool = False) -> bool:
    """A finite number (not a bool), or None where allowed: a figure read back from a curve.json."""
    if value is None:
        return none_ok
    if isinstance(value, bool):
        return False
    return (isinstance(value, float) and abs(value) < float("inf")) or (isinstance(value, int) and abs(value) <= 2**53)


def row_problem(row: dict) -> str:
    """What is wrong with an executor row read back from a curve.json, or "": `splits` must map
    split names to objects whose `FIELDS` are numbers or null."""
    splits = row.get("splits")
    if not isinstance(splits, dict) or not splits:
        return f"splits = {splits!r}; allowed: an object of splits (train, test, ...)"
    for name, figures in splits.items():
        if not isinstance(figures, dict):
            return f"splits[{name!r}] = {figures!r}; allowed: an object of figures"
        for field in FIELDS:
            value = figures.get(field)
            if not is_figure(value, none_ok=True):
                return f"splits[{name!r}][{field!r}] = {value!r}; allowed: a number or null"
    return ""


def _split(row: dict, split: str, field: str = "success_pct") -> float:
    value = row.get("splits", {}).get(split, {}).get(field)
    return float("nan") if value is None else float(value)


def line(row: dict) -> str:
    """The console line of one row, after the iteration, steps and wall time."""
    parts = [f"{name} {_split(row, name):5.1f}% (pose {_split(row, name, 'pose_success_pct'):5.1f}%)"
             for name in row.get("splits", {})]
    return "success " + ", ".join(parts)


def score(row: dict) -> float:
    """The figure the target is read on: success % over the train split."""
    return _split(row, "train")


def reached(rows: list[dict], target: float) -> str:
    """Where the train success first reached `target` %, else the best row."""
    hit = next((r for r in rows if score(r) >= target), None)
    if hit:
        return f"reached {target:g}% train success at {hit['env_steps']:,d} env steps"
    best = max(rows, key=lambda r: np.nan_to_num(score(r), nan=-1.0))
    return (f"never reached {target:g}% train success: best {score(best):.1f}% (test {_split(best, 'test'):.1f}%) "
            f"at {best['env_steps']:,d} steps, iteration {best['iteration']}")


def plot(rows: list[dict], path: Path, target: float, starts: int) -> None:
    """Success and pose success % per split against environment steps."""
    import matplotlib  # lazy: heavy (matplotlib), only when plotting

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: heavy (matplotlib), only when plotting

    steps = np.array([r["env_steps"] for r in rows]) / 1e6
    splits = [s for s in xe.SPLITS if any(s in r.get("splits", {}) for r in rows)]
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    for i, split in enumerate(splits):
        color = f"C{i}"
        ax.plot(steps, [_split(r, split) for r in rows], "o-", color=color, label=f"{split}: success %")
        ax.plot(steps, [_split(r, split, "pose_success_pct") for r in rows], "s--", color=color, alpha=0.6,
                label=f"{split}: pose success %")
    ax.axhline(target, color="gray", lw=0.8, ls=":")
    ax.set_xlabel("environment steps (M)")
    ax.set_ylabel("% of starts tracked to the clip's end")
    ax.set_ylim(0, 100)
    ax.set_title(f"executor: {starts} starts per clip, UniCon's per-term rule (alpha)", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
