"""`morphmimic evaluate --checkpoint X`: Won & Lee 2019's protocol (METHOD.md A, "Results to
reproduce") on one checkpoint.

    morphmimic evaluate --checkpoint learner/pretrained/lower_biped            # 300 shapes, 30 s
    morphmimic evaluate --checkpoint runs/lower_biped --shapes 20 --episode-s 5 --workers 2
    morphmimic evaluate --checkpoint learner/pretrained/lower_biped --morph --strength 0.5  # Figure 1 morph demo

Prints task achievement (mean cumulative task reward R_task) and the fall-down percentage, and
writes into `--out` (default `<checkpoint dir>/eval`): `results.json` (summary + one record per
shape: parameters, return, task reward, fell, the bodies whose floor contact ended it, seconds,
Vm), `summary.md` (with the falls counted by body), `map_return.png`
(measured return binned over two shape parameters), `map_vm.png` (the sampler's marginal value
from the checkpoint), `best.png` / `worst.png` strips (and GIFs with `--gif`).

`morphmimic evaluate` runs this for a shape controller's checkpoint (`learner/evaluation/registry.py`);
a motion executor's is evaluated per clip by `learner/evaluation/executor/report.py`.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, ClassVar, Literal

import numpy as np

from common.motion.root_height import ROOT_HEIGHT_RULES
from common.config_limits import FINITE, SEED, Limit, above, at_least, between, check_limits, validated
from common.tasks.registry import make_env, task_space
from learner.cli_options import parse_options, refuse, value_list
from learner.evaluation import harness
from learner.evaluation.executor import EXECUTOR_ONLY_OPTIONS
from learner.evaluation.registry import first_value
from learner.evaluation.shape import episodes
from learner import checkpoint
from learner.checkpoint import from_checkpointable
from learner.progress import Progress
from learner.evaluation.shape import plots as eval_plots
from learner.evaluation.shape import morph_demo, swim_metrics


PROG = "morphmimic evaluate"
RootHeightRule = Literal[ROOT_HEIGHT_RULES]
FallRule = Literal["task", "paper"]


@validated
@dataclass(kw_only=True)
class ShapeProtocol:
    """How the shapes are drawn and run: the options `morphmimic evaluate` and `morphmimic
    ablation` share on shape controllers."""

    shapes: int = 300
    """Random shapes (paper: 300)."""
    seed: int = 2019
    """Seed of the shape draws (fixed: every checkpoint sees the same shapes)."""
    episode_s: float = 30.0
    """Episode length in simulated seconds (paper: 30)."""
    workers: int = 1
    """Processes running episodes."""
    fall_rule: FallRule = "task"
    """What ends an episode: the task's own rule (a checkpoint trained with
    --task.imitate.no-shin-contact-is-fall lets the shins touch) or Won & Lee's (any body but the
    feet); both fall-down rates are reported either way."""
    map_params: Annotated[tuple[str, ...], value_list(str, "X Y", nargs=2)] = ()
    """Two shape parameters of the return map (default: the run's sampler.plot_params)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"shapes": at_least(1), "seed": SEED, "episode_s": above(0),
                                          "workers": at_least(1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


@validated
@dataclass(kw_only=True)
class EvaluateOptions(ShapeProtocol):
    checkpoint: str
    """Checkpoint dir, state.pt, run dir or learner/pretrained/<name>."""
    box_scale: float = 1.0
    """Draw the shapes from the box shrunk toward the base shape by this factor, as
    --task.body.shape-box-scale does in training (a curriculum's progress); 1: the paper's protocol."""
    root_height: RootHeightRule | None = None
    """Retarget the reference with this root-height rule instead of the checkpoint's (`morphmimic
    references` compares them)."""
    clearance: float | None = None
    """Retarget with this body clearance (m) instead of the checkpoint's."""
    out: str = ""
    """Output directory (default: <checkpoint dir>/eval)."""
    bins: int = 6
    """Cells per axis of the return map."""
    render: bool = True
    """Write the best/worst strips."""
    gif: bool = False
    """Also write GIFs of the best and worst shapes (with --morph: morph.gif)."""
    morph: bool = False
    """Run the morph demo (learner.evaluation.shape.morph_demo) instead."""
    strength: float | None = None
    """With --morph: scale of the morph's deviation from the base shape (default 1)."""
    schedule: morph_demo.Schedule = ()
    """With --morph: JSON keyframes, e.g. '[[0, {}], [3, {"global_z": 1.3}], [6, {}]]' (default: the
    parameterization's)."""
    every: int | None = None
    """With --morph: rebuild the body every this many control steps (default 1)."""

    LIMITS: ClassVar[dict[str, Limit]] = {**ShapeProtocol.LIMITS, "box_scale": between(0, 1, lo_open=True),
                                          "clearance": between(0, 0.1), "bins": at_least(1), "strength": FINITE,
                                          "every": at_least(1)}

    def validate(self) -> None:
        check_limits(self)


def render_episode(loaded: checkpoint.Loaded, params: np.ndarray, seed: int, episode_s: float, out: Path, stem: str,
                   gif: bool, box_scale: float = 1.0, imitate_overrides: dict | None = None) -> list[str]:
    task = loaded.cfg.task
    task = dataclasses.replace(task, imitate=dataclasses.replace(task.imitate, **(imitate_overrides or {})))
    env = make_env(harness.eval_task(task, episode_s, box_scale), seed=0)
    policy = checkpoint.make_policy(loaded, env.obs_dim, env.act_dim)
    rec = eval_plots.Recorder(every=3 if gif else 6)
    episodes.run_episode(env, policy, params, seed, on_step=rec)
    rec(env, 0)  # the final state too: a shape that falls at once still gets a picture
    rec.close()
    written = [rec.write_strip(out / f"{stem}.png")]
    if gif:
        written.append(rec.write_gif(out / f"{stem}.gif", env.cfg.control_hz / 3))
    return [str(p) for p in written if p is not None]


def markdown(name: str, summary: dict, args: EvaluateOptions, files: list[str], loaded: checkpoint.Loaded) -> str:
    s = summary
    lines = [
        f"# Evaluation of `{name}`", "",
        f"Checkpoint `{loaded.path}` (iteration {loaded.state.get('iteration')}, "
        f"{int(loaded.state.get('env_steps', 0)):,d} env steps); task `{loaded.cfg.task.name}`, "
        f"parameterization `{loaded.cfg.task.body.parameterization}`.",
        f"Protocol: {s['shapes']} random shapes (seed {args.seed}), {args.episode_s:g} s episodes, mean action."
        + ("" if args.root_height is None and args.clearance is None else
           f" Reference retargeted with root height {args.root_height or 'as trained'} and clearance "
           f"{'as trained' if args.clearance is None else format(1e3 * args.clearance, 'g') + ' mm'}, "
           "not as the checkpoint was trained.")
        + ("" if args.box_scale == 1.0 else f" Shapes from the box shrunk x{args.box_scale:g} toward the base shape "
           "(not the paper's protocol, which uses the whole box)."), "",
        "| metric | value |", "|---|---|",
        f"| task achievement (mean cumulative R_task) | {s['task_achievement']:.1f} |",
        f"| fall-down % | {s['fall_down_pct']:.1f} |",
        f"| fall-down % by the paper's rule (any body but the feet) | {s['fall_down_pct_paper_rule']:.1f} |",
        f"| fall-down % on the most extreme 10% of shapes | {s['fall_down_pct_extreme10']:.1f} |",
        f"| mean return (R_imit + R_task + R_reg) | {s['mean_return']:.1f} |",
        f"| mean episode length (s) | {s['mean_seconds']:.1f} |",
        f"| return map min/mean over the grid | {s.get('return_map_uniformity', float('nan')):.2f} |",
        f"| simulator divergences | {s['diverged']} |",
        *swim_rows(s), "",
        *([("Falls by the body whose floor contact ended them (a fall may name several): "
            + ", ".join(f"{b} {n}" for b, n in s["falls_by_body"].items())), ""] if s.get("falls_by_body") else []),
        *(["Fall-down by how far the retargeted reference's root height ranges over the clip "
           "(a range well above the clip's own bob means the retargeting moves the root where the clip does not; "
           "see `morphmimic motion check --random-shape`):", "",
           "| reference root range | shapes | fall-down % |", "|---|---|---|",
           *(f"| {row['root_range']} | {row['shapes']} | "
             f"{'-' if row['fall_down_pct'] is None else format(row['fall_down_pct'], '.0f')} |"
             for row in s["falls_by_ref_root_range"]), ""] if s.get("falls_by_ref_root_range") else []),
        *(["Fall-down by how close the retargeted reference brings a body whose floor contact is a fall to the floor "
           "(under 0: the reference itself puts it into the floor, and a body that follows it falls):", "",
           "| reference clearance | shapes | fall-down % |", "|---|---|---|",
           *(f"| {row['clearance']} | {row['shapes']} | "
             f"{'-' if row['fall_down_pct'] is None else format(row['fall_down_pct'], '.0f')} |"
             for row in s["falls_by_ref_clearance"]), ""] if s.get("falls_by_ref_clearance") else []),
        paper_line(loaded.cfg.task.name), "",
        "Files: " + ", ".join(f"`{Path(f).name}`" for f in files), "",
    ]
    return "\n".join(lines)


PAPER_FALL_DOWN = {"lower_biped": "fall-down 20.7% for the lower-body biped (54.1% without reward normalization)",
                   "quadruped": "fall-down 9.3% for the quadruped (11.1% without reward normalization)"}


def paper_line(task: str) -> str:
    """The summary's line on Won & Lee's own figure for this character (their Table 4 has the
    lower-body biped and the quadruped only) and on how far the protocols differ."""
    figure = (f"{PAPER_FALL_DOWN[task]}" if task in PAPER_FALL_DOWN
              else f"no fall-down figure for this character (`{task}`); its Table 4 has the lower-body biped (20.7%) "
                   "and the quadruped (9.3%)")
    return ("Paper (Won & Lee 2019, 300 shapes, 30 s, 50-100 M transitions): " + figure + ". Task achievement is "
            "this project's own scale and is not comparable with the paper's; every difference from the paper's "
            "protocol is listed in docs/shape-controllers.md (\"How this project's protocol differs from the paper's\").")


def swim_rows(s: dict) -> list[str]:
    """A swimmer's speed, heading and upright rows of the summary table (`swim_metrics`); none for a walker."""
    if "swim_upright_pct" not in s:
        return []
    rule = s.get("swim_target_rule", "length")
    return [f"| swim speed error (% of the target speed, {rule} rule, after the first {swim_metrics.WARMUP_S:g} s) | "
            f"{s.get('swim_speed_error_pct', float('nan')):.1f} |",
            f"| swim speed error against the length rule's target (%) | {s.get('swim_speed_error_length_pct', float('nan')):.1f} |",
            f"| swim heading error (degrees) | {s.get('swim_heading_error_deg', float('nan')):.1f} |",
            f"| time upright (root's up axis within {swim_metrics.UPRIGHT_DEG:g} degrees of the reference's), % | "
            f"{s['swim_upright_pct']:.1f} |",
            f"| mean speed / mean target speed (m/s) | {s.get('swim_speed_m_s', float('nan')):.3f} / "
            f"{s.get('swim_target_speed_m_s', float('nan')):.3f} |"]


def swim_line(s: dict) -> str:
    """The swimmer's figures for the closing line of `evaluate` ("" for a walker)."""
    if "swim_upright_pct" not in s:
        return ""
    return (f"; swimming: speed error {s.get('swim_speed_error_pct', float('nan')):.1f}% "
            f"({s.get('swim_target_rule', 'length')} rule; {s.get('swim_speed_error_length_pct', float('nan')):.1f}% "
            f"against the length rule's target), heading error "
            f"{s.get('swim_heading_error_deg', float('nan')):.1f} deg, upright {s['swim_upright_pct']:.1f}%")


NOT_MORPH = ("shapes", "seed", "episode_s", "workers", "box_scale", "map_params", "bins", "render", "root_height",
             "clearance")
"""Evaluation options the morph demo does not take: refused with --morph rather than ignored."""
MORPH_ONLY = ("strength", "schedule", "every")
"""Morph demo options: refused without --morph."""


def main(argv: list[str]) -> int:
    if any(a.split("=", 1)[0] in EXECUTOR_ONLY_OPTIONS for a in argv):  # named for what they are, not "unrecognized"
        path = first_value(argv, "--checkpoint")
        task = checkpoint.load_trained(path).cfg.task.name if path is not None else "?"
        refuse(PROG, f"--checkpoint {path}: task {task!r} is not the executor; "
                     f"{', '.join(EXECUTOR_ONLY_OPTIONS)} are executor options")
    args = parse_options(EvaluateOptions, argv, prog=PROG, description=__doc__)
    if args.morph:
        ignored = harness.changed_flags(args, NOT_MORPH, {"render": "--no-render"})
        if ignored:
            refuse(PROG, f"{', '.join(ignored)}: not options of the morph demo "
                         "(--morph takes --out, --strength, --schedule, --every, --gif)")
        return morph_demo.run(morph_demo.MorphOptions(
            checkpoint=args.checkpoint, out=args.out, schedule=args.schedule, gif=args.gif,
            strength=1.0 if args.strength is None else args.strength, every=args.every or 1))
    morph_only = harness.changed_flags(args, MORPH_ONLY)
    if args.strength is not None:
        refuse(PROG, f"--strength {args.strength} is a morph demo option: use it with --morph")
    if morph_only:
        refuse(PROG, f"{', '.join(morph_only)}: morph demo options: use them with --morph")
    loaded = checkpoint.load_trained(args.checkpoint)
    task = harness.eval_task(loaded.cfg.task, args.episode_s, args.box_scale)
    try:
        env = make_env(task, seed=0)
    except ValueError as exc:  # e.g. a swimmer's stroke-speed model that is missing or does not fit
        raise SystemExit(f"morphmimic evaluate: {loaded.name}: {exc}") from None
    if env.character.is_swimmer and (args.root_height is not None or args.clearance is not None):
        raise SystemExit(f"--root-height/--clearance: {loaded.name} is a swimmer ({task.name}); its reference has no "
                         "feet to retarget onto the floor")
    space = env.space
    n_shape = getattr(env, "n_shape", space.dim)
    out = Path(args.out) if args.out else loaded.path.parent / "eval"
    out.mkdir(parents=True, exist_ok=True)
    names = list(args.map_params) or list(loaded.cfg.sampler.plot_params) or list(space.names[:2])
    eval_plots.axes_of(space, names)  # a bad --map-params fails now, not after hours of episodes
    shapes = episodes.eval_shapes(space, args.shapes, args.seed)
    t0 = time.monotonic()
    overrides = {"shin_contact_is_fall": True} if args.fall_rule == "paper" else {}
    retarget = loaded.cfg.task.imitate.retarget
    if args.root_height is not None:
        retarget = dataclasses.replace(retarget, root_height=args.root_height)
    if args.clearance is not None:
        retarget = dataclasses.replace(retarget, body_clearance_m=args.clearance)
    if retarget != loaded.cfg.task.imitate.retarget:
        overrides["retarget"] = retarget
    with Progress(f"[evaluate] {loaded.name}", len(shapes), "shapes") as bar:
        results = episodes.evaluate(loaded, shapes, args.episode_s, args.seed, args.workers, bar.callback(),
                                     imitate_overrides=overrides, box_scale=args.box_scale)
    summary = episodes.summarize(results, space, n_shape)
    summary["wall_s"] = time.monotonic() - t0
    meta = {"checkpoint": str(loaded.path), "name": loaded.name, "iteration": int(loaded.state.get("iteration", 0)),
            "env_steps": int(loaded.state.get("env_steps", 0)), "seed": args.seed, "episode_s": args.episode_s,
            "box_scale": args.box_scale, "param_names": list(space.names), "map_params": names,
            "fall_rule": args.fall_rule, "body_digest": episodes.body_digest(env.character.preset),
            "root_height": retarget.root_height, "clearance_m": retarget.body_clearance_m}
    if env.character.is_swimmer:
        meta["swimmer_speed"] = swim_metrics.target_rule(env)
        summary["swim_target_rule"] = meta["swimmer_speed"]

    def write_results() -> None:
        (out / "results.json").write_text(json.dumps({"meta": meta, "summary": summary, "shapes": results}, indent=1) + "\n")

    write_results()  # the episodes are kept even if the maps or the rendering fail; rewritten with them below
    params = np.array([r["params"] for r in results])
    sampler_state = loaded.state.get("sampler")
    if sampler_state:
        sampler_state = from_checkpointable(sampler_state)
    train_space = task_space(loaded.cfg.task)
    vm = eval_plots.vm_of(sampler_state, train_space, params) if sampler_state else None
    for r, v in zip(results, vm if vm is not None else [None] * len(results)):
        r["vm"] = None if v is None else float(v)
    files = []
    grid = eval_plots.plot_return_map(space, params, np.array([r["return"] for r in results]),
                                      np.array([r["fell"] for r in results]), names, out / "map_return.png", args.bins)
    summary["return_map_uniformity"] = eval_plots.uniformity(grid)
    summary["return_map"] = np.where(np.isfinite(grid), grid, -1.0).round(2).tolist()
    files.append(str(out / "map_return.png"))
    vm_png = eval_plots.plot_vm_map(sampler_state, train_space, names, out / "map_vm.png") if sampler_state else None
    if vm_png:
        files.append(str(vm_png))
    if args.render:
        order = sorted(results, key=lambda r: r["return"])
        for stem, r in (("best", order[-1]), ("worst", order[0])):
            files += render_episode(loaded, np.array(r["params"]), args.seed + r["index"], args.episode_s, out, stem, args.gif,
                                    args.box_scale, overrides)
    write_results()
    files.insert(0, str(out / "results.json"))
    (out / "summary.md").write_text(markdown(loaded.name, summary, args, files + [str(out / "summary.md")], loaded))
    print(f"[evaluate] {loaded.name}: task achievement {summary['task_achievement']:.1f}, fall-down "
          f"{summary['fall_down_pct']:.1f}% (paper's rule {summary['fall_down_pct_paper_rule']:.1f}%; {summary['shapes']} shapes"
          f"{'' if args.box_scale == 1.0 else f' in the box x{args.box_scale:g}'}, {args.episode_s:g} s), extreme-10% fall-down "
          f"{summary['fall_down_pct_extreme10']:.1f}%, mean return {summary['mean_return']:.1f}, "
          f"return-map min/mean {summary['return_map_uniformity']:.2f}{swim_line(summary)}; wrote {out}")
    return 0

