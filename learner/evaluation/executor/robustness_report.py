"""Files of `morphmimic robustness` (`learner/evaluation/executor/robustness.py`): the markdown table with UniCon's
Table 2 beside each row, the JSON, and the plot of relative performance against playback speed
and projectile interval (the paper's figures as a second line)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt

from common.tasks.executor.env import PROJECTILE, PROJECTILES
from learner import checkpoint

from learner.evaluation.shape import plots as eval_plots


def projectile_spec() -> dict[str, Any]:
    """The projectile as `common.tasks.executor.env` builds it and `throw_projectile` aims it."""
    return {"mass_kg": PROJECTILE["mass_kg"], "radius_m": PROJECTILE["radius_m"],
            "aim": "from a random horizontal direction, launched at the root's height +-0.3 m, at where the centre "
                   "of mass will be when it arrives (the root's velocity held; gravity bends the path a little)",
            "schedule": f"thrown at control steps 0, N, 2N, ... of each episode (N: the row's interval); {PROJECTILES} "
                        "balls thrown in turn, each parked again 1 s after its throw"}


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100.0 * x:.1f}"


def markdown(loaded: checkpoint.Loaded, base: dict, results: list[dict], protocol: dict) -> str:
    executor = loaded.cfg.task.name == "executor"
    if executor:
        ex = loaded.cfg.task.executor
        who = (f"{len(protocol['clips'])} clips x {protocol['starts']} start frames each (evenly over each clip's first 80%, "
               f"on the tracked frame, mean action, truncated at the clip's end): "
               + ", ".join(f"`{c}`" for c in protocol["clips"]))
        if protocol.get("settings"):
            who += (f". **Evaluated with settings changed from training** (`--set {' '.join(protocol['settings'])}`): the "
                    "trained policy on that body or rule")
        own = f"`{ex.termination}`, alpha {ex.alpha:g}"
        success = "tracked to the clip's end with no reward term below alpha"
        planned = "the clip segment's length at that playback speed"
    else:
        who = (f"{protocol['shapes']} random shapes (seed {protocol['seed']}), {protocol['episode_s']:g} s episodes, "
               "mean action")
        own = "a fall"
        success = "did not fall"
        planned = "the episode length"
    lines = [
        f"# Zero-shot robustness of `{loaded.name}`", "",
        f"Checkpoint `{loaded.path}` (iteration {int(loaded.state.get('iteration', 0))}, "
        f"{int(loaded.state.get('env_steps', 0)):,d} env steps), task `{loaded.cfg.task.name}`. Episodes: {who}.", "",
        f"**Performance** = the mean over these episodes of the return under the checkpoint's own termination rule "
        f"({own}) divided by the episode's planned length in control steps ({planned}): the mean reward per planned "
        "step, steps after termination counting 0 (the raw return would reward slow playback, which takes more steps). "
        "**Relative** = a row's performance / the unperturbed performance over the same episodes "
        f"({base['performance']:.4f}); **success** = {success}. UniCon and DeepMimic: Table 2 of Wang et al. 2020 "
        "(relative performance on one cartwheel clip).", "",
        "| row | relative % | success % | performance | relative mean return % | UniCon % | DeepMimic % |",
        "|---|---|---|---|---|---|---|",
        f"| unperturbed | {_pct(base['relative'])} | {base['success_pct']:.1f} | {base['performance']:.4f} | "
        f"{_pct(base['relative_return'])} | 100 | 100 |",
    ]
    skipped: dict[str, list[str]] = {}
    for r in results:
        paper = r.get("paper") or ("-", "-")
        if "skipped" in r:
            lines.append(f"| {r['row']} | skipped | | | | {paper[0]} | {paper[1]} |")
            skipped.setdefault(r["skipped"], []).append(r["row"])
            continue
        lines.append(f"| {r['row']} | {_pct(r['relative'])} | {r['success_pct']:.1f} | {r['performance']:.4f} | "
                     f"{_pct(r['relative_return'])} | {paper[0]} | {paper[1]} |")
    lines.append("")
    if executor and "projectile" in protocol:
        pj = protocol["projectile"]
        lines += ["**The projectile**: a ball of {:g} kg and {:g} cm radius, launched at {:g} m/s from {:g} m away, aimed "
                  "{}; {}. UniCon gives no size, mass or speed.".format(
                      pj["mass_kg"], 100 * pj["radius_m"], pj["speed_mps"], pj["distance_m"], pj["aim"], pj["schedule"]), ""]
    if executor and "shape" in protocol:
        sh = protocol["shape"]
        box = ", ".join(f"{n} [{lo:g}, {hi:g}]" for n, (lo, hi) in sh["box"].items())
        lines += [f"**The shape row** (not in Table 2): the same (clip, start) episodes, each on {sh['shapes']} body shapes "
                  f"drawn uniformly (seed {sh['seed']}) from the whole box of parameterization `{sh['parameterization']}` "
                  f"({box}); each body built for its episode and the clip retargeted onto it, the position terms "
                  "normalized by the body's size (`morphmimic evaluate --shapes`'s protocol); relative to the "
                  "unperturbed base body. "
                  + ("The checkpoint trained over these shapes." if sh["trained_on_shapes"] else
                     "The checkpoint trained on the base body only: zero-shot."), ""]
    if loaded.cfg.task.name == "executor":
        lines += ["Mass rows scale every body's mass and inertia, and what MuJoCo derives from them "
                  "(`ExecutorEnv.scale_mass`); the effort factors and PD gains stay those of the trained body. Speed rows play the targets at that speed (`ExecutorConfig.speed`).", ""]
    else:
        lines += ["Mass rows scale every body's mass and inertia of each shape after its reset (and what MuJoCo "
                  "derives from them); torque limits and "
                  "PD gains stay those of the shape.", ""]
    if skipped:
        lines += ["Skipped rows:", "", *(f"- {', '.join(names)}: {why}" for why, names in skipped.items()), ""]
    return "\n".join(lines)


def plot(results: list[dict], path: Path, title: str) -> Path | None:
    """Relative performance against speed factor and against projectile interval (and the mass
    rows), with UniCon's and DeepMimic's figures; None when no row of those groups ran."""
    matplotlib.use("Agg")

    groups = [(g, xl) for g, xl in (("speed", "playback speed factor"), ("projectile", "control steps between projectiles"),
                                    ("mass", "body mass factor"))
              if any(r["group"] == g for r in results)]
    if not groups:
        return None
    fig, axes = plt.subplots(1, len(groups), figsize=(4.2 * len(groups), 3.6), dpi=120, squeeze=False)
    for ax, (g, xlabel) in zip(axes[0], groups):
        rows = sorted((r for r in results if r["group"] == g), key=lambda r: r["x"])
        xs = [r["x"] for r in rows]
        if g == "speed":
            xs_all = sorted(xs + [1.0])
            ours = {r["x"]: r.get("relative") for r in rows}
            ours[1.0] = 1.0
            ax.plot(xs_all, [None if ours[x] is None else 100 * ours[x] for x in xs_all], "o-", label="this checkpoint")
            paper = {r["x"]: r["paper"] for r in rows}
            ax.plot(xs_all, [100.0 if x == 1.0 else paper[x][0] for x in xs_all], "s--", label="UniCon (Table 2)")
            ax.plot(xs_all, [100.0 if x == 1.0 else paper[x][1] for x in xs_all], "^:", label="DeepMimic (Table 2)")
        else:
            ys = [None if r.get("relative") is None else 100 * r["relative"] for r in rows]
            ax.plot(xs, ys, "o-" if g != "mass" else "o", label="this checkpoint")
            ax.plot(xs, [r["paper"][0] for r in rows], "s--" if g != "mass" else "s", label="UniCon (Table 2)")
            ax.plot(xs, [r["paper"][1] for r in rows], "^:" if g != "mass" else "^", label="DeepMimic (Table 2)")
            skipped = [r["x"] for r in rows if "skipped" in r]
            if skipped:
                ax.scatter(skipped, [2] * len(skipped), marker="x", c="grey", label="skipped")
        ax.axhline(100, color="grey", lw=0.5)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("relative performance %")
        ax.set_ylim(0, max([110.0] + [100 * r["relative"] + 5 for r in rows if r.get("relative") is not None]))
        ax.legend(fontsize=7, loc="best", framealpha=0.6)
    fig.suptitle(title, fontsize=9)
    return eval_plots.save_figure(fig, path)


def write(loaded: checkpoint.Loaded, base: dict, results: list[dict], protocol: dict, out: Path, wall_s: float) -> list[str]:
    """robustness.json, robustness.png (when a plotted row ran) and robustness.md; their paths."""
    meta = {"checkpoint": str(loaded.path), "name": loaded.name, "task": loaded.cfg.task.name,
            "iteration": int(loaded.state.get("iteration", 0)), "env_steps": int(loaded.state.get("env_steps", 0)),
            "performance": "mean over episodes of (return under the checkpoint's own termination rule) / (planned "
                           "control steps of the episode); relative = row / unperturbed over the same episodes",
            "protocol": protocol, "wall_s": wall_s}
    (out / "robustness.json").write_text(json.dumps({"meta": meta, "unperturbed": base, "rows": results}, indent=1) + "\n")
    files = [str(out / "robustness.json")]
    png = plot(results, out / "robustness.png", f"{loaded.name}: zero-shot robustness (relative to unperturbed)")
    if png:
        files.append(str(png))
    (out / "robustness.md").write_text(markdown(loaded, base, results, protocol)
                                       + "\nFiles: " + ", ".join(f"`{Path(f).name}`" for f in files + ["robustness.md"]) + "\n")
    return files + [str(out / "robustness.md")]
