"""The learning curve of a reach run: at each checkpoint the figures `morphmimic evaluate` reports
for the arm (`reach/episodes.py`: success % within the radius, reached %, the final distance, the
reward per step) on the same targets, the rows and plot `learning_curve` writes for a reach run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from learner import checkpoint
from learner.evaluation.executor.curve import is_figure
from learner.evaluation.reach import episodes

FIELDS = ("success_pct", "reached_pct", "final_distance_mm", "final_distance_mm_median", "time_to_reach_s",
          "reward_per_step")
"""The figures a row keeps (`episodes.summarize` keys)."""
NULLABLE = ("final_distance_mm", "final_distance_mm_median", "time_to_reach_s")
"""Figures that are null when no episode has them (all diverged; none reached the target)."""
DEFAULT_TARGET = 90.0
"""Success % the curve reports reaching."""
DEFAULT_TARGETS = 50


def protocol(targets: int, episode_s: float, seed: int) -> dict[str, Any]:
    """What a row depends on besides the checkpoint (the fields of curve.json that must match for
    its rows to be reused, `learning_curve._earlier_rows`)."""
    return {"task": "reach", "targets": targets, "episode_s": episode_s, "seed": seed,
            "radius_m": episodes.SUCCESS_RADIUS_M}


def measure(loaded: checkpoint.Loaded, proto: dict[str, Any]) -> dict[str, Any]:
    """One checkpoint's figures on the protocol's targets."""
    targets = episodes.eval_targets(loaded, proto["targets"], proto["seed"])
    s = episodes.summarize(episodes.run(loaded, targets, proto["episode_s"], proto["seed"], proto["radius_m"]))
    return {k: s[k] for k in FIELDS}


def row_problem(row: dict) -> str:
    """What is wrong with a reach row read back from a curve.json, or "" (each of `FIELDS` a
    number; time to reach and the distances may be null)."""
    for field in FIELDS:
        nullable = field in NULLABLE
        if not is_figure(row.get(field), none_ok=nullable):
            return f"{field} = {row.get(field)!r}; allowed: a number" + (" or null" if nullable else "")
    return ""


def line(row: dict) -> str:
    """The console line of one row, after the iteration, steps and wall time."""
    dist = row.get("final_distance_mm")
    return (f"success {row['success_pct']:5.1f}% reached {row['reached_pct']:5.1f}% final distance "
            f"{'-' if dist is None else f'{dist:5.0f}'} mm reward/step {row['reward_per_step']:.3f}")


def reached(rows: list[dict], target: float) -> str:
    """Where the success first reached `target` %, else the best row."""
    hit = next((r for r in rows if r["success_pct"] >= target), None)
    if hit:
        return f"reached {target:g}% success at {hit['env_steps']:,d} env steps"
    best = max(rows, key=lambda r: r["success_pct"])
    return (f"never reached {target:g}% success: best {best['success_pct']:.1f}% at {best['env_steps']:,d} steps, "
            f"iteration {best['iteration']}")


def plot(rows: list[dict], path: Path, target: float, proto: dict[str, Any]) -> None:
    """Success and reached % (left axis) and the mean final distance in mm (right axis) against
    environment steps."""
    import matplotlib  # lazy: heavy (matplotlib), only when plotting

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: heavy (matplotlib), only when plotting

    steps = np.array([r["env_steps"] for r in rows]) / 1e6
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    ax.plot(steps, [r["success_pct"] for r in rows], "o-", label="success %")
    ax.plot(steps, [r["reached_pct"] for r in rows], "s--", label="reached %")
    ax.axhline(target, color="gray", lw=0.8, ls=":")
    ax.set_ylim(0, 100)
    ax.set_xlabel("environment steps (M)")
    ax.set_ylabel("% of targets")
    right = ax.twinx()
    right.plot(steps, [np.nan if r["final_distance_mm"] is None else r["final_distance_mm"] for r in rows], "^:",
               color="C3", label="final distance, mm")
    right.set_ylabel("final fingertip distance, mm")
    right.set_ylim(bottom=0)
    handles = ax.get_legend_handles_labels()[0] + right.get_legend_handles_labels()[0]
    ax.legend(handles=handles, fontsize=8)
    ax.set_title(f"reach: {proto['targets']} targets, {proto['episode_s']:g} s, success within "
                 f"{1000 * proto['radius_m']:g} mm", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
