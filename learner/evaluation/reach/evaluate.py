"""`morphmimic evaluate --checkpoint X` for a reach checkpoint: the two-link arm on random targets.

    morphmimic evaluate --checkpoint runs/reach                          # 100 targets, 2 s each
    morphmimic evaluate --checkpoint runs/reach --targets 500 --radius 0.01

Each target (polar angle and radius, uniform over the task's box from a fixed `--seed`) gets one
episode of `--episode-s` (default: the checkpoint's own) from a random start pose, the policy's
mean action. Figures (`reach/episodes.py`): success % (the fingertip ends within `--radius` m of
the target), reached % (within it at some step) and the mean time to reach, the final distance
(mean and median, mm), the reward per step; the same for zero actions beside them, the baseline
a trained arm must beat. Writes into `--out` (default `<checkpoint dir>/eval`): `results.json`
(summary, zero-action summary, one record per target), `summary.md`, and `targets.png` (the
targets in the arm's plane, coloured by the final distance, failures crossed).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from common.config_limits import SEED, Limit, above, between, check_limits, validated
from common.tasks.reach import LINK_M
from learner import checkpoint
from learner.cli_options import parse_options
from learner.evaluation.reach import episodes

PROG = "morphmimic evaluate"


@validated
@dataclass(kw_only=True)
class ReachEvaluateOptions:
    checkpoint: str
    """Checkpoint dir, state.pt or run dir of a reach run."""
    targets: int = episodes.TARGETS
    """Random targets (one episode each)."""
    seed: int = episodes.SEED
    """Seed of the target draws and start poses (fixed: every checkpoint sees the same ones)."""
    episode_s: float | None = None
    """Episode length in simulated seconds (default: the checkpoint's own)."""
    radius: float = episodes.SUCCESS_RADIUS_M
    """Success radius around the target, m."""
    out: str = ""
    """Output directory (default: <checkpoint dir>/eval)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"targets": between(1, 100_000, integer=True), "seed": SEED, "episode_s": above(0),
                                          "radius": between(0.0, sum(LINK_M), lo_open=True)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(ReachEvaluateOptions, argv, prog=PROG, description=__doc__)
    loaded = checkpoint.load_trained(args.checkpoint)
    episode_s = args.episode_s or loaded.cfg.task.episode_s
    out = Path(args.out) if args.out else loaded.path.parent / "eval"
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    targets = episodes.eval_targets(loaded, args.targets, args.seed)
    records = episodes.run(loaded, targets, episode_s, args.seed, args.radius)
    summary = episodes.summarize(records)
    zero = episodes.summarize(episodes.run(loaded, targets, episode_s, args.seed, args.radius, zero_action=True))
    meta = {"checkpoint": str(loaded.path), "name": loaded.name, "task": loaded.cfg.task.name,
            "iteration": int(loaded.state.get("iteration", 0)), "env_steps": int(loaded.state.get("env_steps", 0)),
            "targets": args.targets, "seed": args.seed, "episode_s": episode_s, "radius_m": args.radius,
            "wall_s": time.monotonic() - t0}
    (out / "results.json").write_text(json.dumps({"meta": meta, "summary": summary, "zero_action": zero,
                                                  "episodes": records}, indent=1) + "\n")
    plot_targets(records, out / "targets.png", args.radius, summary)
    (out / "summary.md").write_text(markdown(meta, summary, zero))
    print(f"[evaluate] {loaded.name}: {episodes.line(summary, args.radius)}; zero actions: success "
          f"{zero['success_pct']:.1f}%, reward/step {zero['reward_per_step']:.3f} ({args.targets} targets, "
          f"{episode_s:g} s); wrote {out}")
    return 0


def markdown(meta: dict, s: dict, zero: dict) -> str:
    """summary.md: the figures of the policy and of zero actions side by side."""
    def cell(d: dict, key: str, fmt: str) -> str:
        return "-" if d[key] is None else format(d[key], fmt)

    rows = [("success % (fingertip within the radius at the end)", "success_pct", ".1f"),
            ("reached % (within the radius at some step)", "reached_pct", ".1f"),
            ("time to reach, s (episodes that reached)", "time_to_reach_s", ".2f"),
            ("final distance, mm (mean)", "final_distance_mm", ".1f"),
            ("final distance, mm (median)", "final_distance_mm_median", ".1f"),
            ("reward per step", "reward_per_step", ".3f"), ("diverged episodes", "diverged", "d")]
    lines = [f"# Evaluation of `{meta['name']}` (reach)", "",
             f"Checkpoint `{meta['checkpoint']}` (iteration {meta['iteration']}, {meta['env_steps']:,d} env steps). "
             f"{meta['targets']} random targets (seed {meta['seed']}), {meta['episode_s']:g} s episodes from random start "
             f"poses, mean action; success radius {1000 * meta['radius_m']:g} mm.", "",
             "| figure | policy | zero actions |", "|---|---:|---:|"]
    lines += [f"| {text} | {cell(s, key, fmt)} | {cell(zero, key, fmt)} |" for text, key, fmt in rows]
    return "\n".join(lines + ["", "Files: results.json, targets.png, summary.md", ""])


def plot_targets(records: list[dict], path: Path, radius_m: float, summary: dict) -> None:
    """The targets in the arm's plane, coloured by the fingertip's final distance (mm); a cross
    for a target not ended within the radius; the arm's reach as a circle."""
    import matplotlib  # lazy: heavy (matplotlib), only when plotting

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: heavy (matplotlib), only when plotting

    xy = np.array([[r * np.cos(a), r * np.sin(a)] for a, r in (rec["target"] for rec in records)])
    dist = np.array([np.nan if rec["final_distance_m"] is None else 1000 * rec["final_distance_m"] for rec in records])
    ok = np.array([rec["success"] for rec in records])
    fig, ax = plt.subplots(figsize=(5, 5), dpi=110)
    reach = sum(LINK_M)
    ax.add_patch(plt.Circle((0, 0), reach, fill=False, color="gray", lw=0.8, ls=":"))
    ax.plot([0], [0], "ks", ms=5)
    kw = {"c": dist, "cmap": "viridis_r", "vmin": 0.0, "vmax": float(np.nanmax(dist)) if np.isfinite(dist).any() else 1.0}
    sc = ax.scatter(*xy[ok].T, marker="o", s=28, **{**kw, "c": dist[ok]}) if ok.any() else None
    sc = ax.scatter(*xy[~ok].T, marker="x", s=28, **{**kw, "c": dist[~ok]}) if (~ok).any() else sc
    if sc is not None:
        fig.colorbar(sc, ax=ax, shrink=0.8, label="final fingertip distance, mm")
    ax.set_xlim(-1.1 * reach, 1.1 * reach)
    ax.set_ylim(-1.1 * reach, 1.1 * reach)
    ax.set_aspect("equal")
    ax.set_xlabel("x, m")
    ax.set_ylabel("y, m")
    ax.set_title(f"success {summary['success_pct']:.0f}% within {1000 * radius_m:g} mm (o: success, x: not)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
