"""The `morphmimic` command: one entry point whose subcommands live in their own modules.

Each subcommand module exposes `main(argv: list[str]) -> int`; it is imported only when
chosen, so `morphmimic --help` stays fast and a broken optional part cannot break the rest.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Callable

from common.version import version

COMMANDS: dict[str, tuple[str, str]] = {
    "train": ("learner.main", "train a controller (same as `python -m learner.main`)"),
    "distill": ("learner.distill", "start a torque executor from a PD executor (DAgger), to train on with --resume"),
    "curriculum": ("learner.curriculum", "train through a shape curriculum (box x0.25 ... whole box) in one resumable command"),
    "evaluate": ("learner.evaluation.evaluate", "evaluate a checkpoint: random shapes (Won & Lee), the executor's clips by split (UniCon), reach's targets"),
    "ablation": ("learner.evaluation.ablation", "compare checkpoints on the same shapes (or clips): the ablation table"),
    "references": ("learner.evaluation.shape.reference_survey", "how physical a walker's retargeted reference is over the evaluation's shapes, per root-height rule"),
    "velocity-probe": ("learner.evaluation.executor.velocity_probe", "where an executor's joint-velocity term breaks: per joint, with a foot on the floor, with joints left out"),
    "break-probe": ("learner.evaluation.executor.break_probe", "where an executor's pose terms break: the first to fall, each body's share, the root's lean"),
    "learning-curve": ("learner.evaluation.learning_curve", "every checkpoint of a run evaluated alike, against steps and wall time: fall-down %, the executor's or reach's success"),
    "robustness": ("learner.evaluation.executor.robustness", "zero-shot robustness: speed, projectiles, mass (UniCon Table 2)"),
    "play": ("learner.live.play", "run a checkpoint live or render it to an MP4 (schedulers: dataset, stitch, keyboard, video)"),
    "studio": ("learner.live.studio", "a browser studio: a checkpoint live in 3-D with shape sliders, schedulers, projectiles, plots"),
    "character": ("learner.commands.character", "build a character from a preset and shape values; write MJCF and PNG"),
    "motion": ("learner.commands.motion", "import, view and check motion clips"),
    "stroke-speed": ("learner.tools.stroke_speed", "how fast the base swimmers' strokes carry them, per PD stiffening"),
    "stroke-fit": ("learner.tools.stroke_fit", "measure random swimmer shapes' stroke speeds and fit the per-shape speed model"),
    "keypoints": ("learner.live.keypoints", "convert keypoints of another layout (MJCF keyframe mpos, .npy/.npz) to the video scheduler's joints"),
    "send-poses": ("learner.live.pose_sender", "send a clip's joint positions over UDP to the video scheduler (morphmimic play --scheduler video)"),
    "local-cluster": ("learner.commands.local_cluster", "a Ray head and two worker nodes on this machine, to train on with --mode cluster"),
    "bench": ("learner.bench.cli", "benchmarks: throughput, learner, scaling, capacity, replicas, characters, episodes, env-steps, shape-references, sampler, soak, curve"),
}


def dispatch(prog: str, what: str, table: dict[str, tuple[str | Callable[[list[str]], int], str]],
             argv: list[str]) -> int:
    """Run `table[argv[0]]`'s `main(argv[1:])`: a module's (named by a string, imported only when
    chosen) or the function given; `--help` lists the table; an unknown name, or a command that
    ends with `SystemExit(message)` (a bad checkpoint, say), is a one-line usage error (exit 2). Also the dispatcher of `morphmimic bench` and `morphmimic motion`."""
    width = max(len(name) for name in table)
    lines = [f"usage: {prog} <{what}> [options]   ({prog} <{what}> --help for its options)", "", f"{what}s:"]
    lines += [f"  {name:<{width}}  {text}" for name, (_, text) in table.items()]
    if not argv or argv[0] in ("-h", "--help"):
        print("\n".join(lines))
        return 0
    if argv[0] not in table:
        print(f"{prog}: unknown {what} {argv[0]!r}; choose one of {', '.join(table)}", file=sys.stderr)
        return 2
    target = table[argv[0]][0]
    run = importlib.import_module(target).main if isinstance(target, str) else target
    try:
        return int(run(argv[1:]) or 0)
    except SystemExit as exc:
        if isinstance(exc.code, str):  # a refusal raised as SystemExit(message): one line, a usage error
            print(f"{prog} {argv[0]}: {exc.code}", file=sys.stderr)
            return 2
        raise


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] in (["--version"], ["-V"]):
        print(f"morphmimic {version()}")
        return 0
    try:
        return dispatch("morphmimic", "command", COMMANDS, argv)
    except BrokenPipeError:  # the reader of our output left (`morphmimic --help | head`): nothing to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    raise SystemExit(main())
