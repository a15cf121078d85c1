"""`python -m learner.main` (also `morphmimic train`): train a controller.

    python -m learner.main                          # the default preset, single machine
    python -m learner.main --preset reach-tiny --mode serial
    python -m learner.main --ppo.lr 1e-4 --actors.num-actors 4 --total-env-steps 2000000
    python -m learner.main --help                   # every option, with its default

`--preset NAME` picks the starting configuration; every other option overrides a field of it.
"""

from __future__ import annotations

import argparse
import logging
import sys

import tyro

from learner.config import RunConfig
from learner.presets import PRESETS

DEFAULT_PRESET = "reach"


def parse(argv: list[str]) -> RunConfig:
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--preset", default=DEFAULT_PRESET)
    known, rest = pre.parse_known_args(argv)
    if known.preset not in PRESETS:
        raise SystemExit(f"--preset {known.preset!r} is unknown; presets: {', '.join(PRESETS)}")
    description = (
        __doc__
        + "\npresets (--preset NAME, default "
        + DEFAULT_PRESET
        + "):\n"
        + "\n".join(f"  {name:<{max(map(len, PRESETS))}}  {text}" for name, (text, _) in PRESETS.items())
    )
    try:
        cfg = tyro.cli(RunConfig, default=PRESETS[known.preset][1], args=rest, description=description,
                       prog="python -m learner.main [--preset NAME]")
        # The task's own checks (its parameter space, its clips) before any run folder exists.
        from common.tasks.registry import task_clips, task_space

        task_space(cfg.task)
        task_clips(cfg.task)
        return cfg
    except ValueError as exc:  # __post_init__ validation and the task's checks
        print(f"python -m learner.main: invalid configuration: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    cfg = parse(list(sys.argv[1:] if argv is None else argv))
    from learner.train import train  # after parsing, so --help is fast

    return train(cfg)


if __name__ == "__main__":
    raise SystemExit(main())
