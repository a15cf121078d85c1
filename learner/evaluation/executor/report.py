"""`morphmimic evaluate --checkpoint X` on a UniCon motion executor checkpoint (task "executor";
`morphmimic evaluate` hands such checkpoints here): success per clip over the train and test
split (METHOD.md B "Evaluation"), with files and pictures.

    morphmimic evaluate --checkpoint runs/executor                       # every humanoid clip, 10 starts each
    morphmimic evaluate --checkpoint runs/executor --clips humanoid3d_cartwheel humanoid3d_walk --starts 3
    morphmimic evaluate --checkpoint runs/executor --clips my_clips/ take.bvh --workers 2 --no-render
    morphmimic evaluate --checkpoint runs/executor --zero-action          # the same episodes with zero actions: the baseline
    morphmimic evaluate --checkpoint runs/executor-shape --shapes 20 --starts 3   # every episode on 20 random bodies
    morphmimic evaluate --checkpoint runs/executor-shape --shapes 300 --clips-per-shape 8 --starts 2   # 8 clips per body
    morphmimic evaluate --checkpoint runs/executor-shape --morph --clips humanoid3d_walk   # the body changes as it tracks

--shapes N (seed --seed, default 2019): every (clip, start) on each of N shapes drawn uniformly from
the box of the checkpoint's parameterization (on a base-body checkpoint: zero-shot, the baseline);
records carry their shape, the summary adds per-shape figures, and `shape_map.png` shows success
over two shape parameters (--map-params, --bins) per class, and its worst decile (the success
% over the tenth of the shapes with the lowest success, per split). --clips-per-shape K: each
shape runs only K of the clips (each from the --starts frames), assigned by a seeded balanced
rotation (`xe.shape_clip_assignment`: every clip on about N K / clips shapes), so a library of
hundreds of clips fits hundreds of shapes; the pairs depend only on the clips, N, K and --seed,
so checkpoints evaluated with the same flags meet the same (shape, clip) pairs. Default --out `eval_shapes`.
--morph: `learner/evaluation/executor/morph.py`.

--clips takes clip ids, clip files (.npz, .bvh onto the humanoid, DeepMimic .txt) and folders
of `.npz` clips; the default is every humanoid clip, tagged with its split of the checkpoint's
config (train: trained on; test: UniCon's held-out split; unused: neither, for a checkpoint
trained on a clip list; imported: a file). --starts N start frames per clip, evenly over its
first 80%. What is measured, and why one run per episode serves every criterion:
`learner/evaluation/executor/evaluate.py`.

Writes into `--out` (default `<checkpoint dir>/eval_clips`): `results.json` (meta, summary per
split, class, content, style and clip, one record per episode), `summary.md` (the tables),
`clips.png` (success rate per clip coloured by split, PHC success as dots), `styles.png` (success
over the labelled library's content x style, per split, when it has such takes) and, unless --no-render, `best.png` /
`worst.png` strips of the best and worst clip from its first start (GIFs too with --gif).
Prints one line per split and one overall.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar

import matplotlib
import numpy as np
import matplotlib.pyplot as plt
import tyro
from matplotlib.patches import Patch

from common.config_limits import FINITE, SEED, Limit, at_least, check_limits, validated
from common.params import ParamSpace
from common.motion.errors import ClipError
from common.tasks.executor.rewards import POSE_TERMS, TERMS
from learner.cli_options import parse_options, refuse, value_list
from learner.evaluation import harness
from learner.evaluation.executor import EXECUTOR_ONLY_OPTIONS
from learner import checkpoint

from learner.evaluation.shape import morph_demo
from learner.evaluation.shape import plots as eval_plots

from learner.evaluation.executor import evaluate as xe
from learner.evaluation.executor import morph
from learner.evaluation.executor.camera import CameraView
from learner.progress import Progress

ZERO_NOTE = ("**zero actions, not the policy** (`--zero-action`: for PD targets the humanoid's PD on the reference "
             "itself, for torques no torque; the baseline that shows what the policy adds)")
SPLIT_COLOURS = {"train": "#3b75af", "test": "#ef8636", "unused": "#9e9e9e", "imported": "#519e3e"}


PROG = "morphmimic evaluate"


def clip_source(text: str) -> str:
    """`text` if it names an executor clip to evaluate: a humanoid clip id, a clip file (.npz, .bvh,
    DeepMimic .txt/.json) or a folder of `.npz` clips; else `xe.ClipSelectionError` (a ValueError)
    naming it (`xe.classify_clip_value`)."""
    xe.classify_clip_value(text)
    return text


Clips = Annotated[tuple[str, ...], value_list(clip_source, "CLIP", nargs="+")]
"""`--clips A B ...`: clip ids, clip files or folders of .npz clips, each checked as it is parsed."""
Settings = Annotated[tuple[str, ...], value_list(str, "NAME=VALUE", nargs="+"), tyro.conf.arg(
    name="set", help="Run with these fields of the checkpoint's executor config changed, the policy the same "
                     f"(e.g. ankle_armature=0.1): {', '.join(xe.SETTABLE)}.")]
"""`--set NAME=VALUE ...` (a field named `settings`): the pairs `xe.with_settings` applies."""


@validated
@dataclass(kw_only=True)
class ClipOptions:
    """Which episodes an executor evaluation runs: the options `morphmimic evaluate` and
    `morphmimic ablation` share on executor checkpoints."""

    clips: Clips = ()
    """Clip ids, clip files or folders of .npz clips (default: every humanoid clip, by split)."""
    starts: int = 10
    """Start frames per clip, evenly over its first 80% (deterministic)."""
    workers: int = 1
    """Processes running episodes."""

    LIMITS: ClassVar[dict[str, Limit]] = {"starts": at_least(1), "workers": at_least(1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


MapParams = Annotated[tuple[str, ...], value_list(str, "X Y", nargs=2)]


@validated
@dataclass(kw_only=True)
class ReportOptions(ClipOptions):
    checkpoint: str
    """Checkpoint dir, state.pt or run dir of an executor run."""
    out: str = ""
    """Output directory (default: <checkpoint dir>/eval_clips, with --shapes eval_shapes)."""
    shapes: int = 0
    """Run every (clip, start) on this many random body shapes drawn uniformly from the box of the
    checkpoint's parameterization (seeded by --seed; with --clips-per-shape K only K clips on
    each); on a checkpoint trained on the base body only this is the zero-shot test. 0: the base
    body only."""
    clips_per_shape: int = 0
    """With --shapes N: run only K (this many) of the C clips on each shape, assigned by a seeded,
    balanced rotation (every clip on about N K / C shapes; the same pairs for every checkpoint
    given the same clips, --shapes, --clips-per-shape and --seed); 0: every clip on every shape."""
    seed: int = xe.SHAPE_SEED
    """With --shapes: seed of the shape draws and of the clip rotation (fixed: every checkpoint sees the same bodies)."""
    map_params: MapParams = ()
    """With --shapes: the two shape parameters of shape_map.png (default: the run's sampler.plot_params,
    else the parameterization's first two)."""
    bins: int = 4
    """With --shapes: cells per axis of shape_map.png."""
    morph: bool = False
    """Change the body while the executor tracks the first --clips clip (default humanoid3d_walk):
    learner/evaluation/executor/morph.py; writes morph.json, morph.png into --out (default <checkpoint dir>/morph)."""
    strength: float = 1.0
    """With --morph: scale of the keyframes' deviation from the base body."""
    schedule: morph_demo.Schedule = ()
    """With --morph: JSON keyframes, e.g. '[[0, {}], [3, {"height": 1.3}], [6, {}]]' (default: the parameterization's)."""
    every: int = 1
    """With --morph: change the body every this many control steps."""
    render: bool = True
    """Write the best/worst clip strips."""
    gif: bool = False
    """Also write GIFs of the best and worst clip."""
    zero_action: bool = False
    """Act with zero actions instead of the policy (a PD executor: the humanoid's PD on the reference
    itself; torque: no torque), the baseline that shows what the policy adds; no best/worst strips;
    default --out <checkpoint dir>/eval_clips_zero_action."""
    settings: Settings = ()

    LIMITS: ClassVar[dict[str, Limit]] = {**ClipOptions.LIMITS, "shapes": at_least(0), "clips_per_shape": at_least(0),
                                          "seed": SEED, "bins": at_least(1), "strength": FINITE, "every": at_least(1)}

    def validate(self) -> None:
        check_limits(self)
        if self.clips_per_shape and not self.shapes:
            raise ValueError(f"--clips-per-shape = {self.clips_per_shape} is not allowed without --shapes: give "
                             "--shapes N >= 1 with it (K clips on each of N bodies), or --clips-per-shape 0")


SHAPES_ONLY = ("seed", "map_params", "bins")
"""Options that only act with --shapes: refused without it rather than ignored."""
MORPH_ONLY = ("strength", "schedule", "every")
NOT_MORPH = ("shapes", "clips_per_shape", "seed", "map_params", "bins", "starts", "workers", "zero_action", "settings",
             "render")
"""Evaluation options the morph run does not take (it runs one clip on a schedule of bodies)."""


def select_clips(prog: str, values: tuple[str, ...], loaded: checkpoint.Loaded) -> list[xe.EvalClip]:
    """--clips resolved against the checkpoint's config (empty: its default clips); a clip the
    checkpoint cannot play is a usage error of `prog`."""
    try:
        return xe.resolve_clips(list(values), loaded.cfg.task) if values else xe.default_clips(loaded.cfg.task)
    except (xe.ClipSelectionError, ClipError) as exc:
        refuse(prog, f"--clips: {exc}")


def describe(cfg) -> str:
    """The executor's training settings in a few words."""
    ex = cfg.task.executor
    if ex.clips:
        clips = f"{len(ex.clips)} listed clips"
    else:
        clips = f"{ex.split} split (seed {ex.split_seed})"
    watch = {TERMS: "", POSE_TERMS: " on the pose terms"}.get(tuple(ex.terminate_on), f" on {', '.join(ex.terminate_on)}")
    return (f"{ex.actuation}, {'per-term' if ex.termination == 'per_term' else ex.termination} termination"
            f"{watch if ex.termination == 'per_term' else ''} (alpha {ex.alpha:g}), {ex.clip_draws} clip draws{f' (adaptive, clip-k {cfg.sampler.clip_k:g})' if cfg.sampler.clip_k else ''}, {'reactive init' if ex.reactive_init else 'no reactive init'}"
            f"{f' ({100 * ex.on_frame_share:g}% of starts on the frame)' if ex.on_frame_share else ''}, "
            f"{f'preview {list(ex.preview)}' if ex.preview else f'tau {ex.tau}'}, {clips}")


def _f(x: Any, fmt: str = ".1f") -> str:
    return "-" if x is None else format(x, fmt)


def stats_row(name: str, s: dict[str, Any]) -> str:
    return (f"| {name} | {s['clips']} | {s['episodes']} | {_f(s['success_pct'])} | {_f(s.get('pose_success_pct'))} "
            f"| {_f(s['phc_success_pct'])} | {_f(s['mpjpe_mm'])} | {_f(s['mpjpe_mm_success'])} | {_f(s['reward_per_step'], '.3f')} "
            f"| {_f(s['tracked_pct'])} |")


STATS_HEAD = ("| clips | episodes | success % | pose success % | PHC success % | MPJPE mm | MPJPE mm (successful) | reward/step "
              "| tracked % |")


def markdown(loaded: checkpoint.Loaded, summary: dict, meta: dict, files: list[str]) -> str:
    head = "| group " + STATS_HEAD
    rule = "|---" * 10 + "|"
    lines = [
        f"# Executor evaluation of `{loaded.name}`", "",
        f"Checkpoint `{loaded.path}` (iteration {meta['iteration']}, {meta['env_steps']:,d} env steps); trained with "
        f"{describe(loaded.cfg)}.", "",
        *([f"**Evaluated with settings changed from training** (`--set {' '.join(meta['settings'])}`): the figures "
           "measure the trained policy on that body or rule, not the checkpoint as trained.", ""] if meta.get("settings") else []),
        f"Protocol: {summary['overall']['clips']} clips x {meta['starts']} start frames each (evenly over the clip's "
        f"first {100 * xe.START_SPAN:.0f}%), starting on the tracked frame (no reactive initialization), "
        f"{ZERO_NOTE if meta.get('actions') == 'zero' else 'mean action'}, "
        "the episode truncated at the clip's end. One run per episode with termination off; each criterion is read "
        "off that trajectory (termination only cuts an episode, it does not change it):", "",
        f"- **success**: tracked to the clip's end with no reward term below alpha = {loaded.cfg.task.executor.alpha:g} "
        "(UniCon's per-term rule, for every checkpoint alike) and no simulator divergence;",
        "- **pose success**: the same with the four pose terms only (joint velocity not watched, as the executor "
        "presets train);",
        f"- **PHC success**: the mean global body-position error never above {xe.PHC_THRESHOLD_M:g} m before the clip's end "
        "(Luo et al. 2023's criterion, not cut by UniCon's rule);",
        f"- **MPJPE** (mean root-relative body-position error, mm), **reward/step**: over the episode as the checkpoint's own "
        f"termination rule (`{loaded.cfg.task.executor.termination}`) runs it; MPJPE (successful): over the successful "
        "episodes only; **tracked %**: the share of the clip before the first term fell below alpha.", "",
        "Splits: train = clips the checkpoint trained on; test = UniCon's held-out split of its config; unused = other "
        "humanoid clips it did not train on; imported = files.", "",
        *shape_protocol(loaded, summary, meta),
        "## By split", "", head, rule,
        *(stats_row(k, s) for k, s in summary["splits"].items()),
        stats_row("**all**", summary["overall"]), "",
        *([ceiling_line(summary["zero_action_ceiling"]), ""] if summary.get("zero_action_ceiling") else []),
        *shape_tables(summary.get("shapes"), meta["clips_per_shape"] if meta.get("shape_clips") else 0),
        "## By class", "", "| class " + STATS_HEAD, rule,
        *(stats_row(f"`{k}`", s) for k, s in summary["classes"].items()), "",
        *label_level_table("content", summary.get("contents", {})),
        *label_level_table("style", summary.get("styles", {})),
        "## By clip", "",
        "| clip | split | class | success % | pose success % | PHC success % | MPJPE mm | reward/step | tracked % "
        "| ended most by |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for cid, s in summary["clips"].items():
        ended = next(iter(s["failed_terms"]), "-")
        lines.append(f"| `{cid}` | {s['split']} | `{s['label']}` | {_f(s['success_pct'])} "
                     f"| {_f(s.get('pose_success_pct'))} | {_f(s['phc_success_pct'])} | {_f(s['mpjpe_mm'])} "
                     f"| {_f(s['reward_per_step'], '.3f')} | {_f(s['tracked_pct'])} | {ended} |")
    lines += ["", "Files: " + ", ".join(f"`{Path(f).name}`" for f in files), ""]
    return "\n".join(lines)


def shape_protocol(loaded: checkpoint.Loaded, summary: dict, meta: dict) -> list[str]:
    """The summary's paragraph on the body shapes (`--shapes`); none on the base body alone."""
    sh = summary.get("shapes")
    if not sh:
        return []
    box = ", ".join(f"{n} [{lo:g}, {hi:g}] (base {b:g})" for n, lo, hi, b in zip(sh["names"], sh["low"], sh["high"], sh["base"]))
    trained = loaded.cfg.task.body
    how = (f"The checkpoint trained over body shapes (`--task.body.vary-shape`, parameterization `{trained.parameterization}`"
           f"{'' if trained.shape_box_scale == 1.0 else f', its box shrunk x{trained.shape_box_scale:g} toward the base'}). "
           if trained.vary_shape else
           "**Zero-shot**: the checkpoint trained on the base body only (no `--task.body.vary-shape`); these bodies are "
           "new to it (the baseline a shape executor is compared with). ")
    return [
        f"**Body shapes**: {pairing(meta, sh['count'])} drawn uniformly (numpy "
        f"`default_rng({meta['shape_seed']})`, `ParamSpace.uniform`) from the whole box of parameterization "
        f"`{trained.parameterization}`: {box}. {how}Each episode builds the body of its shape and retargets the clip onto "
        "it (root height and stride by leg length, stance feet kept on the floor), and the two position terms of the "
        "reward are normalized by the body's size as in training with vary-shape (the base body's factor is 1). The "
        f"figures by split, class and clip are over "
        f"{'the shapes each clip ran on' if meta.get('shape_clips') else 'every shape'}; "
        "the start frames are the base body's (retargeting keeps a clip's timing). Success over two shape parameters "
        "per class: `shape_map.png`.", ""]


def pairing(meta: dict, count: int) -> str:
    """Which clips ran on which of the `count` shapes, in the words of the summary's protocol (the
    pairs `meta["shape_clips"]` when --clips-per-shape chose them, else every clip on every shape)."""
    k, selected = meta.get("clips_per_shape", 0), len(meta["clips"])
    if "shape_clips" not in meta:
        cap = f" (`--clips-per-shape {k}` >= the {selected} clips: every clip on every shape)" if k else ""
        return f"every (clip, start) above is run on each of {count} shapes{cap}"
    runs = list(Counter(cid for ids in meta["shape_clips"] for cid in ids).values())
    cover = (f"every clip on {min(runs)}-{max(runs)} shapes" if len(runs) == selected else
             f"{count} x {k} < {selected} clips, so only {len(runs)} of them ran, each on one shape")
    starts = meta["starts"]
    return (f"each of {count} shapes runs {k} of the {selected} selected clips (`--clips-per-shape {k}`), each from "
            f"{starts} start frame{'s' if starts > 1 else ''}: {count * k * starts} episodes. The pairs are a balanced "
            f"rotation (`shape_clip_assignment`): the clip ids sorted, shuffled by numpy "
            f"`default_rng([{meta['shape_seed']}, {xe.CLIP_ROTATION_STREAM}])`, that permutation repeated and cut into "
            f"consecutive blocks of {k}, block j to shape j ({cover}); they depend only on the clips, --shapes, "
            "--clips-per-shape and --seed, so every checkpoint evaluated with the same flags meets the same (shape, "
            "clip) pairs (`results.json` meta `shape_clips`). The shapes are")


def worst_decile_line(sh: dict, clips_per_shape: int = 0) -> str:
    """The worst decile of the success map (`xe.worst_decile`) in one markdown paragraph."""
    figures = "; ".join(f"{'all' if g == 'overall' else g} **{pct:.1f}%** ({len(sh['worst_decile_shapes'][g]['shapes'])} "
                        f"of {sh['worst_decile_shapes'][g]['of']} shapes)"
                        for g, pct in sh["worst_decile_shape_success_pct"].items())
    k = max(w.get("neighbours", 1) for w in sh["worst_decile_shapes"].values())
    caveat = (f" With {clips_per_shape} clips per shape a shape's own success rests on its few clips; the neighbourhood "
              "pools them, but compare the figure between checkpoints evaluated on the same pairs."
              if clips_per_shape else "")
    return (f"**Worst decile of the success map** (`worst_decile_shape_success_pct` in `results.json`): the map read at "
            f"each shape as the pooled success of its {k} nearest shapes (itself included, parameters scaled to the box), "
            f"and the mean of that value over the {100 * sh['worst_share']:.0f}% of shapes where it is lowest: {figures}. "
            "Its unit is the shape, not a cell of `shape_map.png` (the cells change with --map-params and --bins; each "
            "shape is one uniform draw "
            "from the whole box); a split's figure ranks the shapes by their episodes of that split." + caveat)


def shape_tables(sh: dict | None, clips_per_shape: int = 0) -> list[str]:
    """Markdown lines: the per-shape spread, the worst decile of the success map, the most extreme
    shapes against the rest, and each shape's row."""
    if not sh:
        return []
    names = sh["names"]
    spread = lambda d: f"{d['min']:.1f} / {d['median']:.1f} / {d['max']:.1f}"  # noqa: E731
    head = "| group " + STATS_HEAD
    rule = "|---" * 10 + "|"
    lines = [
        "## By body shape", "",
        f"Per-shape success % min / median / max over the {sh['count']} shapes: {spread(sh['success_pct'])}; "
        f"PHC success %: {spread(sh['phc_success_pct'])}.", "",
        worst_decile_line(sh, clips_per_shape), "",
        head, rule,
        stats_row(f"most extreme {100 * sh['extreme_share']:.0f}% of shapes ({len(sh['extreme_shapes'])})", sh["extreme"]),
        *(stats_row(f"  extreme, {k}", v) for k, v in sh["extreme"]["splits"].items()),
        stats_row(f"the other shapes ({sh['count'] - len(sh['extreme_shapes'])})", sh["rest"]),
        *(stats_row(f"  others, {k}", v) for k, v in sh["rest"]["splits"].items()), "",
        "Extremeness: the L2 norm of the shape's parameters mapped so the base body is 0 and each end of the box +-1.", "",
        "| shape | " + " | ".join(names) + " | extremeness | success % | pose success % | PHC success % | MPJPE mm | reward/step |",
        "|---" * (7 + len(names)) + "|",
    ]
    for row in sh["per_shape"]:
        lines.append(f"| {row['index']} | " + " | ".join(f"{row['params'][n]:.3f}" for n in names)
                     + f" | {row['extremeness']:.2f} | {_f(row['success_pct'])} | {_f(row.get('pose_success_pct'))} "
                       f"| {_f(row['phc_success_pct'])} | {_f(row['mpjpe_mm'])} | {_f(row['reward_per_step'], '.3f')} |")
    return lines + [""]


def label_level_table(level: str, groups: dict[str, dict[str, dict]]) -> list[str]:
    """Markdown lines of one table: per content or per style of the two-level labelled takes
    (`xe.by_split`), success, PHC success and MPJPE on each split side by side; none when there
    are no such takes."""
    if not groups:
        return []
    splits = [k for k in xe.SPLITS if any(k in g for g in groups.values())]
    head = f"| {level} | " + " | ".join(f"{k} starts | {k} success % | {k} PHC success % | {k} MPJPE mm" for k in splits) + " |"
    rows = []
    for name, by in groups.items():
        cells = []
        for k in splits:
            s = by.get(k)
            cells.append(" | ".join(["-"] * 4) if s is None else
                         f"{s['episodes']} | {_f(s['success_pct'])} | {_f(s['phc_success_pct'])} | {_f(s['mpjpe_mm'])}")
        rows.append(f"| `{name}` | " + " | ".join(cells) + " |")
    return [f"## By {level} (the labelled library's two levels, each over all its takes of a split)", "", head,
            "|---" * (1 + 4 * len(splits)) + "|", *rows, ""]


def ceiling_line(c: dict) -> str:
    """The zero-action ceiling (`xe.zero_action_ceiling`) in one markdown sentence."""
    splits = "; ".join(f"{k} {s['failed']} of {s['episodes']}" for k, s in c["by_split"].items())
    policy = (f"; the policy tracked {c['policy_success_on_failed']} of them to the end" if "policy_success_on_failed" in c
              else "")
    return (f"**Zero-action ceiling**: {c['failed']} of {c['episodes']} starts ({_f(c['failed_pct'])}%; {splits}) fail "
            f"UniCon's rule within {c['steps']} control steps with zero actions (the PD on the reference itself), "
            f"{c['pose_failed']} by the pose terms alone: success is out of reach there, so the ceiling is "
            f"{_f(c['ceiling_pct'])}% ({_f(c['pose_ceiling_pct'])}% for pose success){policy}.")


MAX_NAMED_CLIPS = 80
"""Above this many clips the per-clip chart sorts the bars by success and names none (a library
run's 486 names would make it metres wide); `styles.png` then shows the library's structure."""


def plot_clips(summary: dict, path: Path, title: str = "") -> Path:
    """Bar chart of the success rate per clip, coloured by split, PHC success as dots; with more
    than `MAX_NAMED_CLIPS` clips, each split's bars sorted by success and unnamed."""
    matplotlib.use("Agg")
    clips = sorted(summary["clips"].items(), key=lambda kv: xe.SPLITS.index(kv[1]["split"]))
    named = len(clips) <= MAX_NAMED_CLIPS
    if not named:
        clips.sort(key=lambda kv: (xe.SPLITS.index(kv[1]["split"]), -kv[1]["success_pct"], -kv[1]["phc_success_pct"]))
    names = [c for c, _ in clips]
    width = 0.35 * len(names) + 1.5 if named else 12.0
    fig, ax = plt.subplots(figsize=(max(5.0, width), 4.2), dpi=120)
    x = range(len(names))
    ax.bar(x, [s["success_pct"] for _, s in clips], color=[SPLIT_COLOURS[s["split"]] for _, s in clips],
           width=0.8 if named else 1.0)
    ax.scatter(x, [s["phc_success_pct"] for _, s in clips], marker="o", s=14 if named else 3, c="black", zorder=3)
    if named:
        ax.set_xticks(list(x), [n.replace("humanoid3d_", "").replace("humanoid/", "") for n in names], rotation=70,
                      fontsize=7, ha="right")
    else:
        ax.set_xticks([])
        ax.set_xlabel(f"{len(names)} clips, each split sorted by success")
    ax.set_ylim(0, 105)
    ax.set_ylabel("success % (bars), PHC success % (dots)")
    present = [k for k in xe.SPLITS if any(s["split"] == k for _, s in clips)]
    ax.legend([Patch(color=SPLIT_COLOURS[k]) for k in present], present, fontsize=7, loc="upper right", framealpha=0.6)
    ax.set_title(title, fontsize=9)
    return eval_plots.save_figure(fig, path)


def plot_styles(records: list[dict], path: Path, title: str = "") -> Path | None:
    """Heat map of success % over the labelled library's content (rows) x style (columns), one
    panel per split (train, test); empty cells: no take of that pair in the split. None (and no
    file) when no episode is of a two-level labelled take."""
    labelled = [(r, xe.content_and_style(r["label"])) for r in records]
    labelled = [(r, cs) for r, cs in labelled if cs is not None]
    if not labelled:
        return None
    matplotlib.use("Agg")
    contents = sorted({cs[0] for _, cs in labelled})
    styles = sorted({cs[1] for _, cs in labelled})
    splits = [k for k in xe.SPLITS if any(r["split"] == k for r, _ in labelled)]
    fig, axes = plt.subplots(1, len(splits), figsize=(0.32 * len(styles) * len(splits) + 3.5, 0.3 * len(contents) + 2.0),
                             dpi=120, squeeze=False)
    for ax, split in zip(axes[0], splits):
        grid = np.full((len(contents), len(styles)), np.nan)
        for i, c in enumerate(contents):
            for j, st in enumerate(styles):
                cell = [r["success"] for r, cs in labelled if r["split"] == split and cs == (c, st)]
                if cell:
                    grid[i, j] = 100.0 * float(np.mean(cell))
        im = ax.imshow(grid, vmin=0, vmax=100, cmap="viridis", aspect="auto")
        ax.set_xticks(range(len(styles)), styles, rotation=70, fontsize=6, ha="right")
        ax.set_yticks(range(len(contents)), contents if ax is axes[0][0] else [""] * len(contents), fontsize=6)
        ax.set_title(f"{split}", fontsize=8)
    fig.colorbar(im, ax=axes[0][-1], shrink=0.8, label="success %")
    fig.suptitle(title, fontsize=9)
    return eval_plots.save_figure(fig, path)


MAP_PREFERENCES = (("leg_length", "scale"), ("height", "thickness"), ("global_z", "global_x"),
                   ("upper_thickness", "lower_thickness"), ("left_leg", "right_leg"), ("leg_length", "arm_length"))
"""Default axes of shape_map.png, the first pair the parameterization has (after the run's own
sampler.plot_params): a body's size along one axis, its build or another limb along the other."""
MAX_PANELS = 12
"""shape_map.png shows at most this many classes (the ones with the most episodes) besides "all";
the rest are merged into "other"."""


def default_map_params(space: ParamSpace, plot_params: tuple[str, ...] = ()) -> tuple[str, ...]:
    """The two parameters of shape_map.png: `plot_params` (the run's sampler.plot_params) when the
    space has both, else the first of `MAP_PREFERENCES` it has, else its first two (one for a
    one-parameter space: the map is then a strip along it)."""
    names = tuple(space.names)
    for pair in ((tuple(plot_params),) if len(plot_params) == 2 else ()) + MAP_PREFERENCES:
        if all(p in names for p in pair):
            return pair
    return names[:2]


def panel_of(label: str) -> str:
    """The shape map's panel of a clip class: a labelled take's content (`root/bandai/<content>/...`),
    else the label's top-level class (`root/locomotion/walk` -> locomotion)."""
    cs = xe.content_and_style(label)
    if cs is not None:
        return cs[0]
    parts = label.split("/")
    return parts[1] if len(parts) > 1 and parts[0] == "root" else parts[0] or "root"


def shape_map_grid(space: ParamSpace, records: list[dict], ij: tuple[int, int | None], bins: int) -> tuple[np.ndarray, np.ndarray]:
    """(success % `[bins, bins']`, episodes per cell) of `records` binned over shape parameters i
    (columns) and j (rows; None: one row), NaN where a cell has no episode."""
    i, j = ij
    params = np.array([r["shape"] for r in records])
    ok = np.array([r["success"] for r in records], dtype=float)
    col = np.clip(np.digitize(params[:, i], np.linspace(space.low[i], space.high[i], bins + 1)) - 1, 0, bins - 1)
    rows = 1 if j is None else bins
    row = np.zeros(len(params), int) if j is None else np.clip(
        np.digitize(params[:, j], np.linspace(space.low[j], space.high[j], bins + 1)) - 1, 0, bins - 1)
    total, count = np.zeros((rows, bins)), np.zeros((rows, bins))
    np.add.at(total, (row, col), ok)
    np.add.at(count, (row, col), 1)
    with np.errstate(invalid="ignore"):
        return np.where(count > 0, 100.0 * total / np.maximum(count, 1), np.nan), count


def plot_shape_map(records: list[dict], space: ParamSpace, names: tuple[str, ...], path: Path, bins: int,
                   title: str = "") -> dict[str, list]:
    """shape_map.png: success % over two shape parameters (`names`, x then y), one panel for every
    episode ("all") and one per class (`panel_of`; the `MAX_PANELS` largest, the rest "other"),
    each cell the mean over its episodes (clips, starts, shapes in it), its episode count written
    in it; empty cells blank; the base body marked +. Returns {panel: success grid (rows y, -1 empty)}."""
    matplotlib.use("Agg")
    i = list(space.names).index(names[0])
    j = list(space.names).index(names[1]) if len(names) > 1 else None
    groups: dict[str, list[dict]] = {}
    for r in records:
        groups.setdefault(panel_of(r["label"]), []).append(r)
    order = sorted(groups, key=lambda k: (-len(groups[k]), k))
    if len(order) > MAX_PANELS:
        other = [r for k in order[MAX_PANELS - 1:] for r in groups[k]]
        order = order[: MAX_PANELS - 1] + ["other"]
        groups["other"] = other
    panels = [("all", records)] + [(k, groups[k]) for k in order]
    cols = min(4, len(panels))
    nrows = -(-len(panels) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(3.2 * cols + 0.8, 2.9 * nrows + 0.6), dpi=110, squeeze=False)
    extent = (space.low[i], space.high[i], *((space.low[j], space.high[j]) if j is not None else (0.0, 1.0)))
    grids: dict[str, list] = {}
    im = None
    for ax, (name, rs) in zip(axes.flat, panels):
        grid, count = shape_map_grid(space, rs, (i, j), bins)
        grids[name] = np.where(np.isfinite(grid), grid, -1.0).round(1).tolist()
        im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis", vmin=0, vmax=100, extent=extent)
        w = (extent[1] - extent[0]) / bins
        h = (extent[3] - extent[2]) / grid.shape[0]
        for (r_, c_), n in np.ndenumerate(count):
            if n:
                ax.text(extent[0] + (c_ + 0.5) * w, extent[2] + (r_ + 0.5) * h, f"{int(n)}", ha="center", va="center",
                        fontsize=6, color="white" if grid[r_, c_] < 60 else "black")
        base = space.default_array
        ax.plot(base[i], base[j] if j is not None else 0.5, marker="+", color="red", markersize=9, mew=1.5)
        ax.set_title(f"{name} ({len(rs)} episodes, {100 * np.mean([r['success'] for r in rs]):.0f}%)", fontsize=8)
        ax.set_xlabel(space.names[i], fontsize=7)
        ax.set_ylabel(space.names[j] if j is not None else "", fontsize=7)
        ax.tick_params(labelsize=6)
        if j is None:
            ax.set_yticks([])
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    fig.colorbar(im, ax=axes, shrink=0.7, label="success % (cell: episodes)")
    fig.suptitle(title, fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return grids


def render_clip(loaded: checkpoint.Loaded, clip: xe.EvalClip, start_s: float, out: Path, stem: str, gif: bool,
                shape: list[float] | None = None) -> list[str]:
    """Strip (and GIF) of one evaluation episode (on body `shape`: the clip's first shape with --shapes)."""

    env = xe.make_eval_env(loaded, [clip], shapes=shape is not None)
    policy = checkpoint.make_policy(loaded, env.obs_dim, env.act_dim)
    rec = eval_plots.Recorder(every=3 if gif else 6)
    xe.run_episode(env, policy, clip.clip_id, start_s, loaded.cfg.task.executor.termination, seed=0,
                   on_step=lambda e, k: rec(CameraView(e), k), params=None if shape is None else np.array(shape))
    rec(CameraView(env), 0)
    rec.close()
    written = [rec.write_strip(out / f"{stem}.png")]
    if gif:
        written.append(rec.write_gif(out / f"{stem}.gif", env.cfg.control_hz / 3))
    return [str(p) for p in written if p is not None]


def best_and_worst(summary: dict) -> tuple[str, str]:
    """Clip ids of the best and the worst clip: by success %, then PHC success %, then reward/step."""
    def key(kv):
        s = kv[1]
        return (s["success_pct"], s["phc_success_pct"], s["reward_per_step"] or 0.0)

    order = sorted(summary["clips"].items(), key=key)
    return order[-1][0], order[0][0]


def evaluate_checkpoint(loaded: checkpoint.Loaded, clips: list[xe.EvalClip], starts: int, workers: int, out: Path,
                        render: bool = False, gif: bool = False, log: str = "evaluate", zero_action: bool = False,
                        settings: list[str] | None = None, shapes: int = 0, seed: int = xe.SHAPE_SEED,
                        map_params: tuple[str, ...] = (), bins: int = 4, clips_per_shape: int = 0) -> dict[str, Any]:
    """Run the evaluation and write results.json, summary.md, clips.png (and the strips);
    returns {"meta", "summary", "episodes", "files"}. `zero_action`: the zero-action baseline
    in the checkpoint's task instead of its policy (no strips: they film the policy). `settings`:
    the `--set` pairs already applied to `loaded` (`xe.with_settings`), recorded in the files.
    `shapes` N > 0: every episode on each of N shapes (`xe.eval_shapes(cfg, N, seed)`), the
    summary per shape too, and shape_map.png over `map_params` (`default_map_params`) with `bins`;
    `clips_per_shape` K > 0: each shape runs only its K clips of `xe.shape_clip_assignment(clips,
    N, K, seed)`, recorded as meta "shape_clips"."""
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    space = xe.shape_space(loaded.cfg.task) if shapes else None
    names = (tuple(map_params) or default_map_params(space, tuple(loaded.cfg.sampler.plot_params))) if shapes else ()
    bad = [n for n in names if n not in space.names] if shapes else []
    if bad or (shapes and len(set(names)) != len(names)):
        raise ValueError(f"--map-params {' '.join(map_params)}: give two different parameters of "
                         f"{', '.join(space.names)}")
    drawn = xe.eval_shapes(loaded.cfg.task, shapes, seed) if shapes else None
    pairs = (xe.shape_clip_assignment([c.clip_id for c in clips], shapes, clips_per_shape, seed)
             if shapes and 0 < clips_per_shape < len(clips) else None)  # K >= the clips: every clip on every shape
    planned = sum(map(len, pairs)) if pairs else len(clips) * max(shapes, 1)
    with Progress(f"[{log}] {loaded.name}", planned * starts, "episodes") as bar:
        records = xe.evaluate(loaded, clips, starts, workers, progress=lambda done, total: bar.set(done, total),
                              zero_action=zero_action, shapes=drawn, shape_clips=pairs)
    summary = xe.summarize(records, clips, space)
    summary["zero_action_ceiling"] = xe.zero_action_ceiling(loaded, clips, starts, workers, records, shapes=drawn,
                                                            shape_clips=pairs)
    meta = {"checkpoint": str(loaded.path), "name": loaded.name, "task": "executor",
            "iteration": int(loaded.state.get("iteration", 0)), "env_steps": int(loaded.state.get("env_steps", 0)),
            "training": describe(loaded.cfg), "termination": loaded.cfg.task.executor.termination,
            "alpha": loaded.cfg.task.executor.alpha, "starts": starts, "start_span": xe.START_SPAN,
            "phc_threshold_m": xe.PHC_THRESHOLD_M, "clips": [c.clip_id for c in clips],
            "sources": {c.clip_id: c.source for c in clips if c.source}, "wall_s": time.monotonic() - t0,
            "actions": "zero" if zero_action else "mean", "settings": list(settings or [])}
    if shapes:
        meta.update(shapes=shapes, shape_seed=seed, shape_names=list(space.names), map_params=list(names),
                    parameterization=loaded.cfg.task.body.parameterization, trained_on_shapes=loaded.cfg.task.body.vary_shape,
                    shape_params=drawn.tolist(), clips_per_shape=clips_per_shape,
                    **({"shape_clips": [list(p) for p in pairs]} if pairs else {}))
    on = f" on {shapes} shapes{f', {clips_per_shape} clips per shape' if clips_per_shape else ''}" if shapes else ""
    result = {"meta": meta, "summary": summary, "episodes": records}
    (out / "results.json").write_text(json.dumps(result, indent=1) + "\n")
    files = [str(out / "results.json"), str(plot_clips(summary, out / "clips.png",
                                                       f"{loaded.name}: success per clip ({starts} starts each"
                                                       f"{on})"))]
    if shapes:
        summary["shapes"]["map"] = plot_shape_map(
            records, space, names, out / "shape_map.png", bins,
            f"{loaded.name}: success over {' x '.join(names)} ({shapes} shapes"
            f"{f', {clips_per_shape} clips each' if clips_per_shape else ''}, seed {seed}"
            f"{'' if loaded.cfg.task.body.vary_shape else '; zero-shot: trained on the base body'})")
        files.append(str(out / "shape_map.png"))
        (out / "results.json").write_text(json.dumps(result, indent=1) + "\n")
    styles_png = plot_styles(records, out / "styles.png", f"{loaded.name}: success by content x style ({starts} starts per take)")
    files += [str(styles_png)] if styles_png else []
    if render and not zero_action:
        best, worst = best_and_worst(summary)
        by_id = {c.clip_id: c for c in clips}
        for stem, cid in (("best", best), ("worst", worst)):
            first = None if drawn is None else next(r["shape"] for r in records if r["clip_id"] == cid)
            files += render_clip(loaded, by_id[cid], 0.0, out, stem, gif, first)
        meta.update(best_clip=best, worst_clip=worst)
        (out / "results.json").write_text(json.dumps(result, indent=1) + "\n")
    files.append(str(out / "summary.md"))
    (out / "summary.md").write_text(markdown(loaded, summary, meta, files))
    return {**result, "files": files}


def line(name: str, group: str, s: dict) -> str:
    return (f"[evaluate] {name} {group}: success {_f(s['success_pct'])}% (pose {_f(s.get('pose_success_pct'))}%, "
            f"PHC {_f(s['phc_success_pct'])}%), "
            f"MPJPE {_f(s['mpjpe_mm'])} mm, reward/step {_f(s['reward_per_step'], '.3f')}, "
            f"{s['clips']} clips x {s['episodes'] // max(s['clips'], 1)} starts")


def run_morph(args: ReportOptions, loaded: checkpoint.Loaded) -> int:
    """`--morph`: the body changes while the executor tracks one clip (`morph.py`)."""
    ignored = harness.changed_flags(args, NOT_MORPH, {"render": "--no-render", "settings": "--set"})
    if ignored:
        refuse(PROG, f"{', '.join(ignored)}: not options of --morph (it takes --clips CLIP, --strength, --schedule, "
                     "--every, --gif, --out)")
    if len(args.clips) > 1:
        refuse(PROG, f"--morph tracks one clip; --clips names {len(args.clips)}")
    clip = select_clips(PROG, args.clips, loaded)[0].clip_id if args.clips else morph.DEFAULT_CLIP
    if clip.startswith("imported/"):
        refuse(PROG, f"--morph: {args.clips[0]} is a file; name a clip id of the humanoid's library")
    out = Path(args.out) if args.out else loaded.path.parent / "morph"
    try:
        result = morph.run(loaded, clip, out, list(args.schedule) or None, args.strength, args.every, args.gif)
    except ValueError as exc:
        refuse(PROG, str(exc))
    m, b = result["morph"], result["base_body"]
    zero = "" if loaded.cfg.task.body.vary_shape else " (zero-shot: trained on the base body)"
    print(f"[morph] {loaded.name}{zero} on {clip}: {m['morphs']} body changes over {m['seconds']:.1f} s; morphing: "
          f"{morph.describe(m)}; base body: {morph.describe(b)}; wrote {', '.join(result['files'])}")
    return 0


def main(argv: list[str]) -> int:
    args = parse_options(ReportOptions, argv, prog=PROG, description=__doc__)
    loaded = checkpoint.load_trained(args.checkpoint)
    if loaded.cfg.task.name != "executor":
        refuse(PROG, f"--checkpoint {args.checkpoint}: task {loaded.cfg.task.name!r} is not the executor; "
                     f"{', '.join(EXECUTOR_ONLY_OPTIONS)} are executor options")
    if args.morph:
        return run_morph(args, loaded)
    misplaced = harness.changed_flags(args, MORPH_ONLY) + ([] if args.shapes else harness.changed_flags(args, SHAPES_ONLY))
    if misplaced:
        refuse(PROG, f"{', '.join(misplaced)}: {'--morph' if set(misplaced) & {'--strength', '--schedule', '--every'} else '--shapes N'} "
                     "options: give them with it")
    try:
        loaded = xe.with_settings(loaded, list(args.settings))
    except ValueError as exc:
        refuse(PROG, str(exc))
    clips = select_clips(PROG, args.clips, loaded)
    if args.shapes:
        space = xe.shape_space(loaded.cfg.task)
        names = tuple(args.map_params)
        if names and (len(set(names)) != 2 or any(n not in space.names for n in names)):
            refuse(PROG, f"--map-params {' '.join(names)}: give two different shape parameters of "
                         f"{loaded.cfg.task.body.parameterization}: {', '.join(space.names)}")
    default_out = "eval_shapes" if args.shapes else "eval_clips"
    out = Path(args.out) if args.out else loaded.path.parent / (default_out + ("_zero_action" if args.zero_action else ""))
    result = evaluate_checkpoint(loaded, clips, args.starts, args.workers, out, render=args.render, gif=args.gif,
                                 zero_action=args.zero_action, settings=list(args.settings), shapes=args.shapes,
                                 seed=args.seed, map_params=tuple(args.map_params), bins=args.bins,
                                 clips_per_shape=args.clips_per_shape)
    s = result["summary"]
    name = f"{loaded.name} (zero action)" if args.zero_action else loaded.name
    for group, stats in s["splits"].items():
        print(line(name, group, stats))
    print(line(name, "all", s["overall"]) + f"; wrote {out}")
    if s.get("shapes"):
        sh = s["shapes"]
        print(f"[evaluate] {name} over {sh['count']} shapes (seed {args.seed}"
              f"{'' if loaded.cfg.task.body.vary_shape else ', zero-shot'}): per-shape success min/median/max "
              f"{sh['success_pct']['min']:.1f}/{sh['success_pct']['median']:.1f}/{sh['success_pct']['max']:.1f}%, "
              f"most extreme {100 * sh['extreme_share']:.0f}% of shapes {_f(sh['extreme']['success_pct'])}% "
              f"against {_f(sh['rest']['success_pct'])}% on the others; worst decile of shapes "
              + ", ".join(f"{'all' if g == 'overall' else g} {pct:.1f}%"
                          for g, pct in sh["worst_decile_shape_success_pct"].items())
              + (f" ({args.clips_per_shape} clips per shape)" if args.clips_per_shape else ""))
    c = s["zero_action_ceiling"]
    print(f"[evaluate] {name} zero-action ceiling: {c['failed']} of {c['episodes']} starts fail within {c['steps']} "
          f"steps with zero actions (pose: {c['pose_failed']}); ceiling {_f(c['ceiling_pct'])}% "
          f"(pose {_f(c['pose_ceiling_pct'])}%)")
    return 0

