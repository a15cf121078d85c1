"""`morphmimic references --preset P`: how physical a walker's retargeted reference is over the
shapes `morphmimic evaluate` draws, per root-height rule and body clearance.

    morphmimic references --preset lower_biped                       # 300 shapes, seed 2019
    morphmimic references --preset lower_biped --rules contact_set contact_smooth --clearances 0 0.01

Won & Lee 2019 (METHOD.md A) retarget the clip to every body; a retargeting that asks what no
body can do shows up as falls a controller cannot avoid. Per (rule, clearance), over the same
shapes (`episodes.eval_shapes`, the evaluation's seed), the reference as the task builds it
(`ImitateEnv.reset`):
- root step: the largest change of the root's height between two frames (`check.root_bob`);
  a walk bobs by a few mm per frame, a jump of centimetres is a vertical jerk;
- root range: how far the root's height ranges over the clip;
- stance foot: the largest |height| of a foot's lowest point on its contact frames (float or
  sinking while it should be planted);
- clearance: how close a body whose floor contact is a fall gets to the floor
  (`check.body_clearance`); under 0 the reference itself falls.
Writes `references.md` and `references.json` into `--out` and prints the table.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, ClassVar, Literal

import numpy as np

from common.config_limits import SEED, Limit, at_least, between, check_limits, validated
from common.motion.check import body_clearance, root_bob
from common.motion.root_height import ROOT_HEIGHT_RULES, foot_heights
from common.tasks.registry import make_env
from common.tasks.shape import references
from learner.cli_options import parse_options, value_list
from learner.evaluation.shape import episodes
from learner.presets import PRESETS

WALKER_TASKS = ("lower_biped", "quadruped", "biped")
Walker = Literal[tuple(name for name, (_, cfg) in PRESETS.items() if cfg.task.name in WALKER_TASKS and "-" not in name)]
"""The walking shape tasks' base presets (not their variants)."""
RootHeightRule = Literal[ROOT_HEIGHT_RULES]


@validated
@dataclass
class ReferencesOptions:
    preset: Walker = "lower_biped"
    """A walking shape task."""
    shapes: int = 300
    """Random shapes (the evaluation's 300)."""
    seed: int = 2019
    """Seed of the shape draws (the evaluation's)."""
    rules: tuple[RootHeightRule, ...] = ROOT_HEIGHT_RULES
    """Root-height rules to compare."""
    clearances: Annotated[tuple[float, ...], value_list(float, "METRES", nargs="+")] = (0.0, 0.01)
    """Body clearances (m) to compare, each with every rule."""
    out: str = ""
    """Output directory (default: none, print only)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"shapes": at_least(1), "seed": SEED, "clearances": between(0, 0.1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        if not self.rules:
            raise ValueError(f"--rules: give one or more of {', '.join(ROOT_HEIGHT_RULES)}")
        check_limits(self)


def survey(preset: str, rule: str, clearance_m: float, shapes: np.ndarray) -> dict[str, float]:
    """The reference figures of one (rule, clearance) over `shapes` (rows of the task's space)."""
    task = PRESETS[preset][1].task
    retarget = dataclasses.replace(task.imitate.retarget, root_height=rule, body_clearance_m=clearance_m)
    task = dataclasses.replace(task, imitate=dataclasses.replace(task.imitate, retarget=retarget))
    env = make_env(task, seed=0)
    flags = references.task_clip(env.preset, env.clip_id, env.timestep_s)[1].flags
    step, span, stance, clear = [], [], [], []
    for shape in shapes:
        env.reset(0, shape)
        q = env.motion.qpos_frames
        r, s = root_bob(q)
        span.append(r)
        step.append(s)
        h, _ = foot_heights(env.model, q, tuple(env.character.foot_geoms))
        stance.append(float(np.abs(h[flags]).max()) if flags.any() else 0.0)
        clear.append(body_clearance(env.model, q, np.flatnonzero(~env.allowed_contact))[0])
    step_a, stance_a, clear_a = np.array(step), np.array(stance), np.array(clear)
    return {"rule": rule, "clearance_m": clearance_m, "shapes": len(shapes),
            "root_step_mm_median": 1e3 * float(np.median(step_a)), "root_step_mm_p90": 1e3 * float(np.percentile(step_a, 90)),
            "root_step_mm_max": 1e3 * float(step_a.max()), "root_range_mm_median": 1e3 * float(np.median(span)),
            "stance_foot_mm_median": 1e3 * float(np.median(stance_a)), "stance_foot_mm_max": 1e3 * float(stance_a.max()),
            "clearance_mm_min": 1e3 * float(clear_a.min()), "shapes_clearance_under_5mm": int(np.sum(clear_a < 0.005)),
            "shapes_clearance_under_0": int(np.sum(clear_a < 0.0))}


def table(rows: list[dict]) -> str:
    lines = ["| root-height rule | clearance | root step, median / p90 / max (mm) | root range, median (mm) "
             "| stance foot off the floor, median / max (mm) | shapes within 5 mm of a fall / into the floor "
             "| lowest clearance (mm) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['rule']} | {1e3 * r['clearance_m']:g} mm | {r['root_step_mm_median']:.1f} / "
                     f"{r['root_step_mm_p90']:.1f} / {r['root_step_mm_max']:.1f} | {r['root_range_mm_median']:.1f} "
                     f"| {r['stance_foot_mm_median']:.1f} / {r['stance_foot_mm_max']:.1f} "
                     f"| {r['shapes_clearance_under_5mm']} / {r['shapes_clearance_under_0']} | {r['clearance_mm_min']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    args = parse_options(ReferencesOptions, argv, prog="morphmimic references", description=__doc__)
    env = make_env(PRESETS[args.preset][1].task, seed=0)
    shapes = episodes.eval_shapes(env.space, args.shapes, args.seed)
    rows = []
    for rule in args.rules:
        for clearance in args.clearances:
            rows.append(survey(args.preset, rule, clearance, shapes))
            print(f"[references] {rule}, clearance {1e3 * clearance:g} mm: done", flush=True)
    text = (f"# The `{args.preset}` reference over {args.shapes} evaluation shapes (seed {args.seed})\n\n"
            f"{table(rows)}\n")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "references.md").write_text(text)
        (out / "references.json").write_text(json.dumps(rows, indent=1) + "\n")
    print(text)
    return 0

