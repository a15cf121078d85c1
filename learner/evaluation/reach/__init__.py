"""The reach task's evaluation: random targets, success within a radius, the fingertip's distance."""

from learner.evaluation.registry import Evaluator

EVALUATOR = Evaluator(evaluate="learner.evaluation.reach.evaluate:main")
