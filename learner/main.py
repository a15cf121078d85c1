"""`morphmimic train` (also `python -m learner.main`): train a controller.

    morphmimic train                          # the default preset, single machine
    morphmimic train --preset reach-tiny --mode serial
    morphmimic train --ppo.lr 1e-4 --actors.num-actors 4 --total-env-steps 2000000
    morphmimic train --help                   # the options a user changes
    morphmimic train --help-all               # every option, with its default

`--preset NAME` picks the starting configuration; every other option overrides a field of it.
"""

from __future__ import annotations

import logging
import sys

from common.tasks.registry import task_check, task_clips, task_space
from learner.cli_options import parse_options, scan_flag, short_help
from learner.config import RunConfig
from learner.expected_returns import first_run_line
from learner.presets import PRESETS
from learner.scalar_sinks import check_logger

DEFAULT_PRESET = "reach"
SHORT_HELP = ["total_env_steps", "name", "mode", "resume", "runs_dir", "ray_address", "seed", "quiet", "logger"]
"""The `RunConfig` fields `--help` shows (with --preset); `--help-all` shows them all."""


def parse(argv: list[str]) -> RunConfig:
    try:
        preset, rest = scan_flag(argv, "--preset", DEFAULT_PRESET)
    except ValueError as exc:
        print(f"python -m learner.main: {exc}; presets: {', '.join(PRESETS)}", file=sys.stderr)
        raise SystemExit(2) from None
    if preset not in PRESETS:
        print(f"python -m learner.main: --preset {preset!r} is unknown; presets: {', '.join(PRESETS)}", file=sys.stderr)
        raise SystemExit(2)
    before_dashes = rest[: rest.index("--")] if "--" in rest else rest
    if "--help-all" in before_dashes:
        rest = ["--help" if a == "--help-all" else a for a in rest]
    elif "-h" in before_dashes or "--help" in before_dashes:
        presets = "; ".join(PRESETS)
        print(short_help(RunConfig, SHORT_HELP, PRESETS[preset][1], "python -m learner.main (morphmimic train)",
                         head=__doc__.split("\n\n")[0],
                         extra=[("--preset NAME", f"the starting configuration, every other option overriding a field of it: "
                                                  f"{presets} (default: {DEFAULT_PRESET}; now: {preset})")]))
        raise SystemExit(0)
    description = (
        __doc__
        + "\npresets (--preset NAME, default "
        + DEFAULT_PRESET
        + "):\n"
        + "\n".join(f"  {name:<{max(map(len, PRESETS))}}  {text}" for name, (text, _) in PRESETS.items())
    )
    cfg = parse_options(RunConfig, rest, prog="python -m learner.main", description=description,
                        default=PRESETS[preset][1])
    try:
        # The task's own checks (its parameter space, its clips) before any run folder exists.
        from sampler.plot import map_axes  # lazy: start-up time of --help (matplotlib)

        space = task_space(cfg.task)
        if cfg.sampler.plot_params:
            map_axes(space, cfg.sampler.plot_params)
        task_clips(cfg.task)
        task_check(cfg.task)
        check_logger(cfg.logger)  # W&B chosen but not installed: one line naming the extra, before anything starts
        return cfg
    except ValueError as exc:  # range checks and the task's checks
        print(f"python -m learner.main: invalid configuration: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    argv = list(sys.argv[1:] if argv is None else argv)
    cfg = parse(argv)
    from learner import run_status  # lazy: start-up time of --help (torch, to read the run's checkpoint)

    finished = run_status.finished_line(cfg)
    if finished:  # nothing to train: said in one line, and Ray is never started
        print(finished, flush=True)
        return 0
    if run_status.is_new(cfg) and not cfg.quiet:
        print(first_run_line(scan_flag(argv, "--preset", DEFAULT_PRESET)[0]), flush=True)
    from learner.signals import Interrupted  # lazy: with train below
    from learner.train import train  # lazy: start-up time of --help (tensorboard, the actors, the sampler)

    try:
        return train(cfg)
    except Interrupted:  # a repeated signal while starting, or while cleaning up after the final checkpoint
        print("[morphmimic] interrupted while starting or cleaning up; log.txt names the last checkpoint", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
