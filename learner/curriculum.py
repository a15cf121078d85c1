"""`python -m learner.curriculum` (also `morphmimic curriculum`): a shape curriculum in one
resumable command.

    python -m learner.curriculum --stages 0.25:2M 0.5:6M 0.75:12M 1:20M -- \\
        --preset lower_biped --name lb-curriculum --ppo.gamma 0.99

Each stage `S:N` trains on the shape box shrunk xS toward the base shape
(`--task.body.shape-box-scale S`) until the run has N environment steps in all, then the next
stage continues the same run (`--resume auto`). Everything after `--` goes to
`python -m learner.main` unchanged, for every stage.

Why: Won & Lee 2019 (METHOD.md A) sample shapes from the whole box from the start; on this
2-core machine the lower biped learned to walk only with the box grown from x0.25 to the whole
box in stages (`learner/pretrained/lower_biped-curriculum`, which took seven commands).

Resumable: stop it with Ctrl-C (the learner checkpoints) and run the same command again; the
stages the run's newest checkpoint has already passed are skipped. A stage's steps count from
the start of the run, so `--total-env-steps` and `--task.body.shape-box-scale` belong to the
stages, not after `--`. The learning-rate schedule `linear` would decay to zero at every stage's
end, so it is refused.
"""

from __future__ import annotations

import argparse
import re
import sys
from dataclasses import dataclass
from pathlib import Path

_OWNED = ("--total-env-steps", "--total_env_steps", "--task.body.shape-box-scale", "--task.body.shape_box_scale")
_SUFFIX = {"": 1, "k": 1_000, "K": 1_000, "M": 1_000_000, "G": 1_000_000_000}


@dataclass(frozen=True)
class Stage:
    box_scale: float
    until_steps: int


def parse_stage(text: str) -> Stage:
    """`S:N` (S in (0, 1], N a positive step count such as 2000000, 2e6, 2M or 500k) -> Stage;
    ValueError naming the text and the form otherwise."""
    match = re.fullmatch(r"\s*([0-9.eE+-]+)\s*:\s*([0-9.eE+]+)\s*([kKMG]?)\s*", text)
    form = "give S:N with S the box scale in (0, 1] and N the run's total steps, e.g. 0.5:6M"
    if match is None:
        raise ValueError(f"stage {text!r}: {form}")
    try:
        scale, steps = float(match.group(1)), float(match.group(2)) * _SUFFIX[match.group(3)]
    except ValueError:
        raise ValueError(f"stage {text!r}: {form}") from None
    if not 0.0 < scale <= 1.0:
        raise ValueError(f"stage {text!r}: box scale {scale:g} must be in (0, 1] (1: the whole box)")
    if not (steps >= 1 and steps == int(steps) and steps < 1e13):
        raise ValueError(f"stage {text!r}: step count {steps:g} must be a whole number from 1 to 1e13")
    return Stage(scale, int(steps))


def check_stages(stages: list[Stage]) -> list[Stage]:
    """The stages if each ends later than the one before (ValueError otherwise)."""
    for before, after in zip(stages, stages[1:]):
        if after.until_steps <= before.until_steps:
            raise ValueError(f"stage {after.box_scale:g}:{after.until_steps} must end after the stage before it "
                             f"({before.box_scale:g}:{before.until_steps}): N counts the run's steps from its start")
    return stages


def steps_done(run_dir: Path) -> int:
    """Environment steps of the run's newest loadable checkpoint (0 without one)."""
    from learner import checkpoint

    latest = checkpoint.load_latest(run_dir / "ckpt")
    return 0 if latest is None else int(latest[1].get("env_steps", 0))


def _without_resume(argv: list[str]) -> list[str]:
    out, skip = [], False
    for arg in argv:
        if skip:
            skip = False
        elif arg == "--resume":
            skip = True
        elif not arg.startswith("--resume="):
            out.append(arg)
    return out


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ours, learner_argv = (argv[: argv.index("--")], argv[argv.index("--") + 1 :]) if "--" in argv else (argv, [])
    p = argparse.ArgumentParser(prog="python -m learner.curriculum", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--stages", nargs="+", required=True, metavar="S:N",
                   help="box scale S in (0, 1] until the run's N-th environment step, in order (e.g. 0.25:2M 1:20M)")
    args = p.parse_args(ours)
    try:
        stages = check_stages([parse_stage(s) for s in args.stages])
    except ValueError as exc:
        p.error(str(exc))
    owned = [a for a in learner_argv if a.split("=")[0] in _OWNED]
    if owned:
        p.error(f"{owned[0].split('=')[0]} is set by each stage (--stages S:N); leave it out after --")

    from learner import main as learner_main

    cfg = learner_main.parse(learner_argv + ["--total-env-steps", str(stages[-1].until_steps)])
    if cfg.ppo.lr_schedule == "linear":
        p.error("--ppo.lr-schedule linear decays to zero at each stage's end; use constant or adaptive")
    if not cfg.task.body.vary_shape:
        p.error(f"preset/task {cfg.task.name!r} trains on the base shape only (vary_shape off): it has no box to grow")
    run_dir = Path(cfg.runs_dir) / cfg.name
    for i, stage in enumerate(stages, 1):
        done = steps_done(run_dir)
        label = f"[curriculum] stage {i}/{len(stages)} (box x{stage.box_scale:g} until {stage.until_steps:,d} steps)"
        if done >= stage.until_steps:
            print(f"{label}: done ({done:,d} steps)", flush=True)
            continue
        stage_argv = (_without_resume(learner_argv) + ["--resume", "auto"]) if done else list(learner_argv)
        print(f"{label}: from {done:,d} steps", flush=True)
        code = learner_main.main(stage_argv + ["--task.body.shape-box-scale", str(stage.box_scale),
                                               "--total-env-steps", str(stage.until_steps)])
        if code:
            return code
        done = steps_done(run_dir)
        if done < stage.until_steps:
            print(f"{label}: stopped at {done:,d} steps; run the same command to continue", flush=True)
            return 0
    print(f"[curriculum] all {len(stages)} stages done: {steps_done(run_dir):,d} steps in {run_dir}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
