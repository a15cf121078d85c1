"""Starting a run from another run's trained networks (`--init-from`): fine-tuning.

The shape executor (issue 55 item 5) starts from the fixed-body executor: the same task, the
same observation layout (the body's shape parameters come first in both; the fixed-body run saw
them pinned to the base shape), the same networks. What carries over is the policy (its weights,
action noise and observation statistics), the value function and an adaptive step size; the
optimizer's moments, the counters, the iteration and the sampler start fresh, as for a new run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from common.policy import ObsNormalizer
from learner.learner import Learner


def constant_inputs(normalizer: ObsNormalizer) -> torch.Tensor:
    """Boolean mask `[obs_dim]` of the observation entries the source run never saw vary
    (standard deviation below the normalizer's `STD_FLOOR`): the shape parameters of a
    fixed-body run, features a task pins."""
    return normalizer.var.sqrt() < ObsNormalizer.STD_FLOOR


@torch.no_grad()
def _silence_inputs(net: torch.nn.Sequential, mask: torch.Tensor) -> None:
    """Zero the first layer's weights from the masked inputs, so the network computes what it
    computed while those inputs were constant (normalized to 0), and learns their use from 0."""
    first = net[0]
    assert isinstance(first, torch.nn.Linear), "an MLP starts with its linear layer"
    first.weight[:, mask] = 0.0


def start_from(learner: Learner, state: dict[str, Any]) -> int:
    """Load a checkpoint's policy and value function into a fresh learner (fine-tuning).

    Inputs the source never saw vary get zero first-layer weights in both networks, so the run
    begins with the source's behaviour exactly and grows their use by gradient; their trained
    weights were never updated (a constant input normalizes to 0 and carries no gradient) and
    would project the new variation randomly. The observation statistics are the source's, with
    its count, so one batch of the new run cannot shift the inputs the policy was trained on (a
    count cut to one iteration's let the first update move them by half and the first PPO step
    reach a KL of 0.87). Constant inputs among the observation's first `learner.space.dim`
    entries, where the executor and the shape tasks put the episode's parameters (the body's
    shape), start with the mean and variance of the uniform over the parameter box (Won & Lee
    2019 draw shapes from it): otherwise their variance, weighted against every step the source
    saw, would take that many steps to reach the box's. An adaptive step size starts where the
    source's ended (from the preset's 1e-4, a fresh Adam's first update moved the trained policy
    by a KL of 0.84 against the target's 0.01). Returns how many inputs were silenced.
    KeyError, RuntimeError or ValueError when the state does not fit (`train.fine_tuned_learner`
    turns it into one line)."""
    learner.load_networks(state)
    normalizer = learner.policy.normalizer
    normalizer.check()
    mask = constant_inputs(normalizer)
    _silence_inputs(learner.policy.mean_net, mask)
    _silence_inputs(learner.value.net, mask)
    _box_statistics(normalizer, mask, learner.space.low_array, learner.space.high_array)
    learner.ppo.restore_lr(float(state["lr"]))
    return int(mask.sum())


@torch.no_grad()
def _box_statistics(normalizer: ObsNormalizer, mask: torch.Tensor, low: np.ndarray, high: np.ndarray) -> None:
    """Mean (low + high) / 2 and variance (high - low)^2 / 12 for the masked entries among the
    first len(low) (the parameters; a pinned one, low == high, keeps what it had)."""
    p = min(len(low), mask.shape[0])
    lo, hi = torch.as_tensor(low[:p], dtype=torch.float64), torch.as_tensor(high[:p], dtype=torch.float64)
    reset = mask[:p] & (hi > lo)
    normalizer.mean[:p] = torch.where(reset, (lo + hi) / 2.0, normalizer.mean[:p])
    normalizer.var[:p] = torch.where(reset, (hi - lo).square() / 12.0, normalizer.var[:p])


def describe(path: Path, state: dict[str, Any], silenced: int) -> str:
    """The run log's line saying where the networks came from."""
    return (f"[morphmimic] --init-from {path}: policy and value function of iteration {int(state.get('iteration', -1))} "
            f"({int(state.get('env_steps', 0)):,d} env steps); {silenced} observation inputs it never saw vary start "
            f"with zero weights; its step size carries over; optimizer moments, counters and sampler start fresh")
