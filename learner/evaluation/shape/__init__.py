"""The shape controllers' evaluation (Won & Lee 2019): random shapes, fall-down and task achievement."""

from learner.evaluation.registry import Evaluator

EVALUATOR = Evaluator(evaluate="learner.evaluation.shape.evaluate:main",
                      ablation="learner.evaluation.shape.ablation:main")
