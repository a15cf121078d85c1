"""The `morphmimic` command: one entry point whose subcommands live in their own modules.

Each subcommand module exposes `main(argv: list[str]) -> int`; it is imported only when
chosen, so `morphmimic --help` stays fast and a broken optional part cannot break the rest.
"""

from __future__ import annotations

import importlib
import sys

COMMANDS: dict[str, tuple[str, str]] = {
    "train": ("learner.main", "train a controller (same as `python -m learner.main`)"),
    "evaluate": ("learner.evaluation.evaluate", "evaluate a checkpoint: random shapes (Won & Lee) or, for the executor, clips by split (UniCon)"),
    "ablation": ("learner.evaluation.ablation", "compare checkpoints on the same shapes (or clips): the ablation table"),
    "robustness": ("learner.evaluation.robustness", "zero-shot robustness: speed, projectiles, mass (UniCon Table 2)"),
    "play": ("learner.live.play", "run a checkpoint live or render it to an MP4 (schedulers: dataset, stitch, keyboard, video)"),
    "studio": ("learner.live.studio", "a browser studio: a checkpoint live in 3-D with shape sliders, schedulers, projectiles, plots"),
    "character": ("common.characters.cli", "build a character from a preset and shape values; write MJCF and PNG"),
    "motion": ("common.motion.cli", "import, view and check motion clips"),
    "send-poses": ("common.tasks.pose_sender", "send a clip's joint positions over UDP to the video scheduler (morphmimic play --scheduler video)"),
    "bench": ("learner.bench.cli", "benchmarks: throughput | characters | episodes | sampler | soak"),
}


def usage() -> str:
    width = max(len(name) for name in COMMANDS)
    lines = ["usage: morphmimic <command> [options]   (morphmimic <command> --help for its options)", "", "commands:"]
    lines += [f"  {name:<{width}}  {text}" for name, (_, text) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"morphmimic: unknown command {name!r}; choose one of {', '.join(COMMANDS)}", file=sys.stderr)
        print(usage(), file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[name][0])
    return int(module.main(rest) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
