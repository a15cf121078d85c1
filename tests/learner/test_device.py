"""`--learner.device`: the learner and the sampler's marginal value fit on a device, weights to
the actors as CPU arrays. The cuda cases run where there is a GPU and are skipped, saying so,
where there is none (CI's machine); the refusal of cuda without a GPU runs where there is none."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from common import device as devices
from learner import checkpoint
from learner.config import LearnerConfig
from learner.presets import PRESETS
from learner.train import train
from sampler.marginal_value import MarginalValue

ROOT = Path(__file__).resolve().parents[2]
HAS_CUDA = torch.cuda.is_available()
DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not HAS_CUDA, reason="no CUDA GPU on this machine"))]


def test_auto_takes_the_gpu_only_where_there_is_one():
    assert devices.resolve("auto").type == ("cuda" if HAS_CUDA else "cpu")
    assert devices.resolve("cpu").type == "cpu"


@pytest.mark.skipif(HAS_CUDA, reason="this machine has a GPU: cuda is allowed here")
def test_cuda_without_a_gpu_is_one_line_exit_2_and_no_run_folder(tmp_path):
    with pytest.raises(ValueError, match="--learner.device cuda: this process sees no CUDA GPU"):
        devices.resolve("cuda")
    proc = subprocess.run(
        [sys.executable, "-m", "learner.main", "--preset", "reach-tiny", "--mode", "serial", "--learner.device", "cuda",
         "--runs-dir", str(tmp_path), "--name", "gpu"],
        cwd=ROOT, capture_output=True, text=True, timeout=120, check=False,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        ("python -m learner.main: --learner.device cuda: this process sees no CUDA GPU "
         f"(torch {torch.__version__}, torch.cuda.is_available() is False); give cpu, or auto to use a GPU only where there is one")
    ]
    assert not (tmp_path / "gpu").exists()


@pytest.mark.parametrize("device", DEVICES)
def test_a_run_on_the_device_publishes_cpu_weights_and_checkpoints_that_load_anywhere(device, tmp_path):
    cfg = dataclasses.replace(PRESETS["reach-tiny"][1], runs_dir=str(tmp_path), quiet=True, mode="serial", max_iterations=3,
                              total_env_steps=10**6, learner=LearnerConfig(device=device))
    published = []

    def record(run, metrics) -> None:
        assert run.learner.device.type == device
        assert next(run.learner.policy.parameters()).device.type == device
        published.append(run.learner.weights_msg())

    assert train(cfg, on_iteration=record) == 0
    assert len(published) == 3
    for msg in published:
        assert all(isinstance(v, np.ndarray) and v.dtype in (np.float32, np.float64) for v in msg.tensors.values())
    state = checkpoint.load_latest(tmp_path / "reach-tiny" / "ckpt")[1]
    assert all(t.device.type == "cpu" for t in state["policy"].values())
    assert state["iteration"] == 3 and float(state["sampler"]["meta"]["vm"]["steps"]) > 0


@pytest.mark.parametrize("device", DEVICES)
def test_the_marginal_value_fit_on_the_device_matches_the_cpu_fit(device):
    rng = np.random.default_rng(0)
    params = rng.uniform(-1, 1, size=(512, 2))
    values = 10 + 5 * params[:, 0] - 3 * params[:, 1] ** 2
    fits = {}
    for where in ("cpu", device):
        vm = MarginalValue(np.array([-1.0, -1.0]), np.array([1.0, 1.0]), seed=3, device=where)
        vm.fit(params, values, steps=200, minibatch=128, rng=np.random.default_rng(1))
        fits[where] = vm(params)
        assert vm.state()[1]["net/0.weight"].dtype == np.float32
    assert np.abs(fits[device] - values).mean() < 1.0
    np.testing.assert_allclose(fits[device], fits["cpu"], atol=1e-3)


def test_a_saved_config_with_a_device_of_another_kind_is_refused_naming_it():
    import json

    from learner.config import RunConfig

    raw = json.loads(RunConfig().to_json())
    for section, value, flag in (("learner", 3, "--learner.device"), ("sampler", "gpu", "--sampler.device")):
        bad = {**raw, section: {**raw[section], "device": value}}
        with pytest.raises(ValueError, match=f"{flag} = {value!r}: give cpu, cuda or auto"):
            RunConfig.from_json(json.dumps(bad))
