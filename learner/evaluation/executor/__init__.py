"""The motion executor's evaluation (UniCon): success per clip over the train and test splits."""

from learner.evaluation.registry import Evaluator

EVALUATOR = Evaluator(evaluate="learner.evaluation.executor.report:main",
                      ablation="learner.evaluation.executor.ablation:main")

EXECUTOR_ONLY_OPTIONS = ("--clips", "--starts", "--zero-action", "--set", "--clips-per-shape")
"""Options only the motion executor's evaluation takes."""
