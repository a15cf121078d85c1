"""`morphmimic evaluate --checkpoint X`: the evaluation of the checkpoint's task.

    morphmimic evaluate --checkpoint learner/pretrained/lower_biped            # 300 shapes, 30 s
    morphmimic evaluate --checkpoint runs/executor --clips humanoid3d_walk --starts 3

A shape controller's checkpoint: Won & Lee 2019's protocol (`learner/evaluation/shape/evaluate.py`,
`morphmimic evaluate --checkpoint <shape checkpoint> --help`); a motion executor's: UniCon's, per
clip (`learner/evaluation/executor/report.py`); the reach arm's: success within a radius of random
targets (`learner/evaluation/reach/evaluate.py`). Which one runs is the task's family in
`learner/evaluation/registry.py`.
"""

from __future__ import annotations

from learner.evaluation.registry import dispatch


def main(argv: list[str]) -> int:
    return dispatch("evaluate", argv, "--checkpoint")
