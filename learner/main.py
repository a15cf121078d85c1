"""`python -m learner.main` (also `morphmimic train`): train a controller.

    python -m learner.main                          # the default preset, single machine
    python -m learner.main --preset reach-tiny --mode serial
    python -m learner.main --ppo.lr 1e-4 --actors.num-actors 4 --total-env-steps 2000000
    python -m learner.main --help                   # every option, with its default

`--preset NAME` picks the starting configuration; every other option overrides a field of it.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import logging
import sys

import tyro

from common.config_limits import deferred_checks, validate_tree
from learner.config import RunConfig
from learner.presets import PRESETS

DEFAULT_PRESET = "reach"


def one_line(box: str) -> str:
    """tyro's boxed parse error as one line: its message, then the expected form or the flag it
    suggests (`--ppo.lr abc` -> "Error parsing --ppo.lr: could not convert string to float:
    'abc'; expected: --ppo.lr FLOAT")."""
    lines = [line for line in box.splitlines() if line.strip()]
    if len(lines) >= 2 and lines[0].lstrip()[:1] in ("╭", "+", "-"):
        lines = lines[1:-1]  # the top border (with the box's title) and the bottom one
    rows = [line.strip().strip("│|").strip() for line in lines]
    sections, current = [], []
    for row in rows:
        if not row:
            continue
        if set(row) <= set("─-=+"):
            sections.append(current)
            current = []
        else:
            current.append(row)
    sections.append(current)
    sections = [sec for sec in sections if sec]
    if len(sections) > 1 and len(sections[0]) == 1 and len(sections[0][0]) < 40 and not set(sections[0][0]) & set(":'\""):
        sections = sections[1:]  # a plain-text box's title ("Value error") on a row of its own
    if not sections:
        return box.strip() or "invalid arguments"
    text = " ".join(sections[0])
    for sec in sections[1:]:
        if sec[0].startswith(("Argument helptext", "Perhaps you meant")) and len(sec) > 1:
            text += ("; expected: " if sec[0].startswith("Argument") else "; did you mean: ") + sec[1]
    return text


def parse(argv: list[str]) -> RunConfig:
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--preset", default=DEFAULT_PRESET)
    known, rest = pre.parse_known_args(argv)
    if known.preset not in PRESETS:
        print(f"python -m learner.main: --preset {known.preset!r} is unknown; presets: {', '.join(PRESETS)}", file=sys.stderr)
        raise SystemExit(2)
    description = (
        __doc__
        + "\npresets (--preset NAME, default "
        + DEFAULT_PRESET
        + "):\n"
        + "\n".join(f"  {name:<{max(map(len, PRESETS))}}  {text}" for name, (text, _) in PRESETS.items())
    )
    # NOTE: tyro builds the nested configs; their range checks wait until it is done, so a bad
    # value is reported here in one line (tyro would draw a box around the ValueError).
    errors = io.StringIO()
    try:
        with deferred_checks(), contextlib.redirect_stderr(errors):
            cfg = tyro.cli(RunConfig, default=PRESETS[known.preset][1], args=rest, description=description,
                           prog="python -m learner.main [--preset NAME]")
    except SystemExit as exc:
        if exc.code:
            print(f"python -m learner.main: {one_line(errors.getvalue())}", file=sys.stderr)
        raise
    try:
        validate_tree(cfg)
        # The task's own checks (its parameter space, its clips) before any run folder exists.
        from common.tasks.registry import task_check, task_clips, task_space
        from sampler.plot import map_axes

        space = task_space(cfg.task)
        if cfg.sampler.plot_params:
            map_axes(space, cfg.sampler.plot_params)
        task_clips(cfg.task)
        task_check(cfg.task)
        return cfg
    except ValueError as exc:  # range checks and the task's checks
        print(f"python -m learner.main: invalid configuration: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    cfg = parse(list(sys.argv[1:] if argv is None else argv))
    from learner.train import train  # after parsing, so --help is fast

    return train(cfg)


if __name__ == "__main__":
    raise SystemExit(main())
