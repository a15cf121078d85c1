"""`morphmimic curriculum`: a shape curriculum in one resumable command.

    morphmimic curriculum --stages 0.25:2M 0.5:6M 0.75:12M 1:20M -- \\
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
stages, not after `--`; `--max-iterations` is refused too (a stage ends at its step count). A
`--resume PATH` after `--` forks the first stage from that checkpoint (a shipped controller,
say); once the run has checkpoints of its own, every stage continues them. The run's own
checkpoint must be of the same task, parameterization, sampler k and reward normalization as
the command's (a `-uniform` run is not continued as an adaptive one). The box only grows, and
every stage runs with the same flags: to change another setting between stages (a discount, a
KL stop), stop the command and resume with `python -m learner.main` as
`learner/pretrained/lower_biped-curriculum/README.md` did. The learning-rate schedule `linear`
would decay to zero at every stage's end, so it is refused.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import logging
import re
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Annotated, ClassVar

from common.config_limits import Limit, validated
from learner.cli_options import parse_options, refuse, value_list

PROG = "morphmimic curriculum"

_OWNED = ("--total-env-steps", "--total_env_steps", "--task.body.shape-box-scale", "--task.body.shape_box_scale",
          "--max-iterations", "--max_iterations")
_SUFFIX = {"": 1, "k": 1_000, "K": 1_000, "M": 1_000_000, "G": 1_000_000_000}
_SAME_RUN = (("task", "name"), ("task", "body", "parameterization"), ("task", "body", "vary_shape"),
             ("task", "imitate", "reward_normalization"), ("sampler", "k"))
"""Fields a run's checkpoint must share with the command for a stage to continue it."""


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
        scale = float(match.group(1))
        steps = Decimal(match.group(2)) * _SUFFIX[match.group(3)]
    except (ValueError, InvalidOperation):
        raise ValueError(f"stage {text!r}: {form}") from None
    if not 0.0 < scale <= 1.0:
        raise ValueError(f"stage {text!r}: box scale {scale:g} must be in (0, 1] (1: the whole box)")
    if not (steps.is_finite() and 1 <= steps < Decimal("1e13") and steps == steps.to_integral_value()):
        raise ValueError(f"stage {text!r}: step count {steps:f} must be a whole number from 1 to 1e13")
    return Stage(scale, int(steps))


def check_stages(stages: list[Stage]) -> list[Stage]:
    """The stages if each ends later than the one before and none shrinks the box (ValueError otherwise)."""
    for before, after in itertools.pairwise(stages):
        if after.until_steps <= before.until_steps:
            raise ValueError(f"stage {after.box_scale:g}:{after.until_steps} must end after the stage before it "
                             f"({before.box_scale:g}:{before.until_steps}): N counts the run's steps from its start")
        if after.box_scale < before.box_scale:
            raise ValueError(f"stage {after.box_scale:g}:{after.until_steps} shrinks the box of the stage before it "
                             f"({before.box_scale:g}:{before.until_steps}): a curriculum only grows it")
    return stages


def run_state(run_dir: Path) -> tuple[int, dict | None]:
    """(environment steps, resolved config) of the run's newest loadable checkpoint; (0, None)
    without one."""
    from learner import checkpoint  # lazy: start-up time of morphmimic curriculum --help (torch)

    latest = checkpoint.load_latest(run_dir / "ckpt")
    if latest is None:
        return 0, None
    state = latest[1]
    config = state.get("config")
    return int(state.get("env_steps", 0)), (json.loads(config) if isinstance(config, str) else None)


def mismatch(saved: dict, cfg) -> str | None:
    """The first `_SAME_RUN` field in which the checkpoint's config `saved` differs from `cfg`,
    as "field: checkpoint X, command Y"; None if they agree."""
    mine = dataclasses.asdict(cfg)
    for path in _SAME_RUN:
        a, b = saved, mine
        for key in path:
            a = a.get(key) if isinstance(a, dict) else None
            b = b.get(key) if isinstance(b, dict) else None
        if a != b:
            return f"{'.'.join(path)}: checkpoint {a!r}, command {b!r}"
    return None


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


@validated
@dataclass
class CurriculumOptions:
    stages: Annotated[tuple[Stage, ...], value_list(parse_stage, "S:N", lambda st: f"{st.box_scale:g}:{st.until_steps}", nargs="+")]
    """Box scale S in (0, 1] until the run's N-th environment step, in order (e.g. 0.25:2M 1:20M)."""

    LIMITS: ClassVar[dict[str, Limit]] = {}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_stages(list(self.stages))


def main(argv: list[str]) -> int:
    argv = list(argv)
    ours, learner_argv = (argv[: argv.index("--")], argv[argv.index("--") + 1 :]) if "--" in argv else (argv, None)
    stages = list(parse_options(CurriculumOptions, ours, prog=PROG, description=__doc__).stages)
    if learner_argv is None or not any(a == "--preset" or a.startswith("--preset=") for a in learner_argv):
        refuse(PROG, "give the run after --, with its preset: ... -- --preset lower_biped --name NAME [learner.main options]")
    owned = [a for a in learner_argv if a.split("=")[0] in _OWNED]
    if owned:
        refuse(PROG, f"{owned[0].split('=')[0]} is set by each stage (--stages S:N); leave it out after --")

    from learner import main as learner_main  # lazy: start-up time of morphmimic curriculum --help (torch)
    # lazy: start-up time of morphmimic curriculum --help (torch, tensorboard)
    from learner.train import STOP_BUDGET, train_until_stop

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")

    cfg = learner_main.parse(learner_argv + ["--total-env-steps", str(stages[-1].until_steps)])
    if cfg.ppo.lr_schedule == "linear":
        refuse(PROG, "--ppo.lr-schedule linear decays to zero at each stage's end; use constant or adaptive")
    if not cfg.task.body.vary_shape:
        refuse(PROG, f"preset/task {cfg.task.name!r} trains on the base shape only (vary_shape off): it has no box to grow")
    run_dir = Path(cfg.runs_dir) / cfg.name
    done, saved = run_state(run_dir)
    if saved is not None and (why := mismatch(saved, cfg)):
        refuse(PROG, f"run {run_dir} was trained as another run ({why}); give another --name")
    own = saved is not None
    if not own and cfg.resume not in ("auto", "never"):
        # a fork: the stages count from the forked checkpoint's steps
        from learner import checkpoint  # lazy: start-up time of morphmimic curriculum --help (torch)

        try:
            done = int(checkpoint.load(Path(cfg.resume)).get("env_steps", 0))
        except checkpoint.CheckpointError as exc:
            refuse(PROG, f"--resume {cfg.resume}: {exc}")
    try:
        for i, stage in enumerate(stages, 1):
            label = f"[curriculum] stage {i}/{len(stages)} (box x{stage.box_scale:g} until {stage.until_steps:,d} steps)"
            if done >= stage.until_steps:
                print(f"{label}: done ({done:,d} steps)", flush=True)
                continue
            stage_argv = (_without_resume(learner_argv) + ["--resume", "auto"]) if own else list(learner_argv)
            print(f"{label}: from {done:,d} steps", flush=True)
            reason = train_until_stop(learner_main.parse(
                stage_argv + ["--task.body.shape-box-scale", str(stage.box_scale), "--total-env-steps", str(stage.until_steps)]))
            done, own = run_state(run_dir)[0], True
            if reason != STOP_BUDGET or done < stage.until_steps:
                print(f"{label}: {reason} at {done:,d} steps; run the same command to continue", flush=True)
                return 0
    except KeyboardInterrupt:  # Ctrl-C between stages, before a learner has its handler in place
        print(f"\n[curriculum] stopped between stages at {run_state(run_dir)[0]:,d} steps; run the same command to continue",
              flush=True)
        return 0
    print(f"[curriculum] all {len(stages)} stages done: {done:,d} steps in {run_dir}", flush=True)
    return 0
