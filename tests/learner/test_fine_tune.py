"""`--init-from`: a run that starts from another run's networks (issue 55 item 5, the shape
executor fine-tuned from the fixed-body one). The fine-tuned run begins with the source's
behaviour exactly, its parameter inputs take the box's statistics, and a checkpoint of another
task or a path without one is refused in one line before anything is written."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from learner import checkpoint
from learner.fine_tune import start_from
from learner.learner import Learner
from learner.presets import PRESETS
from learner.train import train


def _executor(vary_shape: bool):
    cfg = PRESETS["executor-tiny"][1]
    body = dataclasses.replace(cfg.task.body, vary_shape=vary_shape)
    return dataclasses.replace(cfg, task=dataclasses.replace(cfg.task, body=body))


def test_a_fixed_body_executor_starts_a_shape_run_with_its_own_behaviour():
    fixed, shaped = Learner(_executor(False)), Learner(_executor(True))
    p = shaped.space.dim
    assert fixed.obs_dim == shaped.obs_dim and p > 0
    assert np.all(fixed.space.low_array == fixed.space.high_array), "the fixed body pins its shape"
    rng = np.random.default_rng(0)
    seen = rng.normal(0.0, 1.0, (512, fixed.obs_dim))
    seen[:, :p] = fixed.space.default_array  # what the fixed-body run observed: its one shape
    fixed.policy.normalizer.update(torch.as_tensor(seen))
    silenced = start_from(shaped, fixed.state_dict())
    assert silenced == p

    norm = shaped.policy.normalizer
    lo, hi = shaped.space.low_array, shaped.space.high_array
    assert torch.allclose(norm.mean[:p], torch.as_tensor((lo + hi) / 2, dtype=torch.float64))
    assert torch.allclose(norm.var[:p], torch.as_tensor((hi - lo) ** 2 / 12, dtype=torch.float64))
    assert torch.equal(norm.mean[p:], fixed.policy.normalizer.mean[p:]) and norm.count == 512

    # Any shape in the box: the fine-tuned networks act and value as the source did on its body.
    new = torch.as_tensor(rng.normal(0.0, 1.0, (64, fixed.obs_dim)), dtype=torch.float32)
    new[:, :p] = torch.as_tensor(shaped.space.uniform(rng, 64), dtype=torch.float32)
    old = new.clone()
    old[:, :p] = torch.as_tensor(fixed.space.default_array, dtype=torch.float32)
    with torch.no_grad():
        assert torch.allclose(shaped.policy.distribution(new).mean, fixed.policy.distribution(old).mean, atol=1e-6)
        assert torch.allclose(shaped.value(shaped.policy.normalizer(new)), fixed.value(fixed.policy.normalizer(old)), atol=1e-5)
        # ... and the source's own behaviour is not what a fresh network does.
        assert not torch.allclose(Learner(_executor(True)).policy.distribution(new).mean,
                                  shaped.policy.distribution(new).mean, atol=1e-3)


def test_init_from_trains_on_and_refuses_what_does_not_fit(tmp_path, capsys):
    source = dataclasses.replace(PRESETS["reach-tiny"][1], runs_dir=str(tmp_path), name="source", mode="serial",
                                 quiet=True, max_iterations=1)
    assert train(source) == 0
    tuned = dataclasses.replace(source, name="tuned", init_from=str(tmp_path / "source"))
    assert train(tuned) == 0
    log = (tmp_path / "tuned" / "log.txt").read_text()
    assert "--init-from" in log and "policy and value function of iteration 1" in log
    assert checkpoint.load_latest(tmp_path / "tuned" / "ckpt")[1]["iteration"] == 1  # a new run, not a resume

    for init_from, why in ((str(tmp_path / "nowhere"), "no state.pt there"),):
        with pytest.raises(SystemExit) as exc:
            train(dataclasses.replace(source, name="bad", init_from=init_from))
        assert exc.value.code == 2 and why in capsys.readouterr().err
    other = dataclasses.replace(_executor(True), runs_dir=str(tmp_path), name="other", mode="serial", quiet=True,
                                init_from=str(tmp_path / "source"))
    with pytest.raises(SystemExit) as exc:
        train(other)
    assert exc.value.code == 2 and "a checkpoint of task 'reach'; this run trains 'executor'" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists() and not (tmp_path / "other").exists()
