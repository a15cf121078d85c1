"""What the evaluation's film strips (`learner.evaluation.shape.plots.Recorder`) read of an
executor environment: its model, data and character, the humanoid's root as body 1."""

from __future__ import annotations


class CameraView:
    """What `eval_plots.Recorder` reads of an environment, for the executor's humanoid."""

    def __init__(self, env):
        self._env = env
        self.root_body = 1

    model = property(lambda self: self._env.model)
    data = property(lambda self: self._env.data)
    character = property(lambda self: self._env.character)
