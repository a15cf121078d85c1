"""The observation normalizer's update is bounded (issue 54, item 1): one adversarial batch
moves its statistics by a bounded factor, never by orders of magnitude, and a checkpoint is not
written with a statistic no bounded update can produce."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from common.policy import ObsNormalizer
from learner import checkpoint
from learner.learner import Learner
from learner.presets import PRESETS


def _trained(rng: np.random.Generator, batches: int = 5) -> ObsNormalizer:
    norm = ObsNormalizer(3)
    for _ in range(batches):
        norm.update(torch.as_tensor(rng.normal([0.0, 5.0, -2.0], [1.0, 0.1, 3.0], size=(256, 3))))
    return norm


def test_one_batch_of_3e38_moves_the_statistics_by_a_bounded_factor() -> None:
    """What one batch of 3e38 observations did on main: mean 2.7e35, variance 8e73."""
    norm = _trained(np.random.default_rng(0))
    mean, std = norm.mean.clone(), norm.var.sqrt()
    norm.update(torch.full((256, 3), 3e38, dtype=torch.float32))
    step = (norm.mean - mean).abs() / std.clamp(min=ObsNormalizer.STD_FLOOR)
    assert float(step.max()) <= ObsNormalizer.MAX_MEAN_STEP + 1e-9
    assert float((norm.var.sqrt() / std).max()) <= ObsNormalizer.MAX_STD_STEP + 1e-9
    assert norm.limited_updates == 1
    norm.check()
    # Honest data brings it back: the poisoned batch is one batch among many.
    rng = np.random.default_rng(1)
    for _ in range(40):
        norm.update(torch.as_tensor(rng.normal([0.0, 5.0, -2.0], [1.0, 0.1, 3.0], size=(256, 3))))
    assert float((norm.mean - mean).abs().max()) < 1.0


def test_a_first_batch_is_clipped_and_a_nonfinite_one_changes_nothing() -> None:
    norm = ObsNormalizer(2)
    norm.update(torch.tensor([[3e38, -3e38], [3e38, 1.0]]))
    assert float(norm.mean.abs().max()) <= ObsNormalizer.RAW_LIMIT and float(norm.var.max()) <= ObsNormalizer.RAW_LIMIT**2
    norm.check()
    before = {k: v.clone() for k, v in norm.state_dict().items()}
    norm.update(torch.tensor([[float("nan"), 0.0]]))
    assert all(torch.equal(before[k], v) for k, v in norm.state_dict().items())


def test_honest_batches_are_not_held_back() -> None:
    """Batches of one distribution (the first small) give exactly the pooled statistics."""
    rng = np.random.default_rng(2)
    data = [rng.normal(3.0, 2.0, size=(n, 4)) for n in (64, 2000, 333, 1024)]
    norm = ObsNormalizer(4)
    for d in data:
        norm.update(torch.as_tensor(d))
    assert norm.limited_updates == 0
    np.testing.assert_allclose(norm.var.numpy(), np.concatenate(data).var(0), rtol=1e-10)


@pytest.mark.parametrize("name, index, value", [("mean", 3, 2.7e35), ("var", 0, 8e73), ("var", 5, float("nan")),
                                                ("count", 0, float("inf"))])
def test_a_checkpoint_is_not_written_with_an_absurd_statistic(tmp_path, name: str, index: int, value: float) -> None:
    learner = Learner(dataclasses.replace(PRESETS["reach-tiny"][1], seed=0))
    learner.state_dict()  # sound statistics: fine
    buffer = getattr(learner.policy.normalizer, name)
    buffer.view(-1)[index] = value
    with pytest.raises(ValueError, match=rf"observation normalizer {name}\[{index if name != 'count' else 0}\]"):
        checkpoint.save(tmp_path / "ckpt", 1, learner.state_dict(), keep=3)
    assert checkpoint.list_checkpoints(tmp_path / "ckpt") == []
