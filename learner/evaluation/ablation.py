"""`morphmimic ablation --checkpoints A B ...`: the ablation table of the checkpoints' task, every
checkpoint evaluated alike.

    morphmimic ablation --checkpoints runs/lower_biped runs/lower_biped-uniform --out ablation/lower_biped

Shape controllers: Won & Lee 2019's ablations (`learner/evaluation/shape/ablation.py`); motion
executors: UniCon's table (`learner/evaluation/executor/ablation.py`). The first checkpoint's task
chooses (`learner/evaluation/registry.py`), which refuses the others unless they are of its family.
"""

from __future__ import annotations

from learner.evaluation.registry import dispatch


def main(argv: list[str]) -> int:
    return dispatch("ablation", argv, "--checkpoints")
