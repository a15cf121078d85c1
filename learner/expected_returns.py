"""What return each preset reaches when trained, as this project measured it: the one line a
first run prints (`first_run_line`), so a user knows what the numbers in the log are heading for
before spending hours on them.

Every figure comes from a record in the repository (`Measured.source`); a preset with none says
so. Two kinds of figure, never mixed up: `training` is the log's own `return` column (the mean
return of training episodes), `evaluate` is the mean return over 300 random shapes in 30 s
episodes with the mean action (`morphmimic evaluate`), which the training log's column does not
show. A figure was measured on the preset of its day, sometimes with the extra flags `how`
names; presets have changed since in small ways, so it is a guide, not a test.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Measured:
    value: str
    """The return, as the record gives it (a number, or a range)."""
    kind: str
    """"training": the log's `return` column; "evaluate": `morphmimic evaluate`'s mean return."""
    env_steps: int
    """Environment steps trained when it was measured."""
    source: str
    """The record, a path in the repository."""
    how: str = ""
    """How the run differed from the plain preset command, if it did."""


_LB20 = "docs/experiments/2026-12-05-lower-biped-paper-ablations-20M.md"
_LB20_HOW = ("through `morphmimic curriculum` (box x0.25 to 2 M steps, x0.5 to 5 M, x0.75 to 10 M) with "
             "--ppo.gamma 0.99; mean of its last 4 checkpoints")
_LB20_FORK = ("forked at 12 M steps from that lower_biped curriculum run, with --ppo.gamma 0.99; mean of its "
              "last 4 checkpoints")
_Q5 = "docs/experiments/2026-12-03-quadruped-paper-ablations-5M.md"
_Q5_HOW = "forked from learner/pretrained/quadruped at 2.2 M steps, the paper's ablation arm"

EXPECTED: dict[str, Measured] = {
    "reach": Measured("37.6", "training", 400_000, "docs/ppo.md", "mean over the last third of the run"),
    "lower_biped": Measured("4851.1", "evaluate", 20_000_768, _LB20, _LB20_HOW),
    "lower_biped-uniform": Measured("4434.8", "evaluate", 20_000_768, _LB20, _LB20_FORK),
    "lower_biped-nonorm": Measured("4284.9", "evaluate", 20_000_768, _LB20, _LB20_FORK),
    "quadruped": Measured("5912.0", "evaluate", 7_303_168, _Q5, _Q5_HOW),
    "quadruped-uniform": Measured("6131.9", "evaluate", 7_303_168, _Q5, _Q5_HOW),
    "quadruped-nonorm": Measured("5752.2", "evaluate", 7_303_168, _Q5, _Q5_HOW),
    "quadruped-fixedshape": Measured("1453.5", "evaluate", 7_303_168, _Q5, _Q5_HOW),
    "biped": Measured("6232.8", "evaluate", 14_172_160, "learner/pretrained/biped/README.md",
                      "through `morphmimic curriculum` with --ppo.gamma 0.99"),
    "executor": Measured("21-25", "training", 44_078_272, "docs/experiments/2026-12-03-executor-torque-vs-pd-equal-budget.md",
                         "started from a PD policy distilled with `morphmimic distill`; from scratch it did not survive "
                         "the termination rule in 2.8 M steps"),
}
"""Preset -> its measured return when trained. Presets not here have no measurement yet."""

SMOKE_TESTS = ("reach-tiny", "lower_biped-tiny", "executor-tiny")
"""Presets that run a few iterations to test the machinery: their return means nothing."""


def first_run_line(preset: str) -> str:
    """The line a new run of `preset` prints before it starts."""
    if preset in SMOKE_TESTS:
        return f"[morphmimic] new run: preset {preset} is a smoke test of a few iterations; its return is not expected to grow"
    m = EXPECTED.get(preset)
    if m is None:
        return (f"[morphmimic] new run: preset {preset} has no measured return when trained yet "
                "(learner/expected_returns.py lists the presets that have one)")
    how = f"; {m.how}" if m.how else ""
    if m.kind == "training":
        return (f"[morphmimic] new run: preset {preset} reaches a return of about {m.value} (the log's return column) "
                f"when trained for {m.env_steps:,d} env steps ({m.source}{how})")
    return (f"[morphmimic] new run: preset {preset}, trained for {m.env_steps:,d} env steps, scores a mean return of "
            f"about {m.value} in `morphmimic evaluate`, not the log's return column ({m.source}{how})")
