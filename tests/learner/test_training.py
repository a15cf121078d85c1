"""End-to-end runs of `python -m learner.main`: learning in serial mode within a step budget,
local (private Ray) mode through the CLI, resume, and a clean stop on SIGTERM."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from common.policy import GaussianPolicy
from common.tasks.registry import make_env
from learner import checkpoint
from learner.config import RunConfig
from learner.presets import PRESETS
from learner.train import train
from tests.learner.processes import alive, descendants

ROOT = Path(__file__).resolve().parents[2]


def _tiny(tmp_path: Path, **overrides) -> RunConfig:
    base = PRESETS["reach-tiny"][1]
    return dataclasses.replace(base, runs_dir=str(tmp_path), quiet=True, **overrides)


def _mean_return(policy: GaussianPolicy, cfg: RunConfig, episodes: int = 20) -> float:
    env = make_env(cfg.task, seed=123)
    rng = np.random.default_rng(5)
    total = 0.0
    for _ in range(episodes):
        obs, _ = env.reset(int(rng.integers(1 << 30)), env.space.uniform(rng, 1)[0])
        done = False
        while not done:
            action, _ = policy.act(obs[None], deterministic=True)
            obs, r, term, trunc, _ = env.step(action[0])
            total += r
            done = term or trunc
    return total / episodes


def test_reach_learns_in_serial_mode_within_step_budget(tmp_path):
    """The learning test: 16 iterations of 4096 steps. An untrained policy scores about 1-3;
    the threshold of 15 is reached only by a policy that moves its fingertip onto targets."""
    cfg = dataclasses.replace(
        PRESETS["reach"][1], runs_dir=str(tmp_path), name="learn", mode="serial", quiet=True,
        total_env_steps=16 * 4096, checkpoint_every=100,
    )
    untrained = GaussianPolicy(12, 2, cfg.policy)
    assert train(cfg) == 0
    path, state = checkpoint.load_latest(tmp_path / "learn" / "ckpt")
    assert state["env_steps"] >= cfg.total_env_steps
    trained = GaussianPolicy(12, 2, cfg.policy)
    trained.load_state_dict(state["policy"])
    before, after = _mean_return(untrained, cfg), _mean_return(trained, cfg)
    assert before < 8.0, before
    assert after > 15.0, (before, after)


def test_resume_continues_counters_and_sampler(tmp_path):
    cfg = _tiny(tmp_path, mode="serial", max_iterations=2, total_env_steps=10**6)
    assert train(cfg) == 0
    first = checkpoint.load_latest(tmp_path / "reach-tiny" / "ckpt")[1]
    assert first["iteration"] == 2
    assert train(dataclasses.replace(cfg, max_iterations=4)) == 0
    second = checkpoint.load_latest(tmp_path / "reach-tiny" / "ckpt")[1]
    assert second["iteration"] == 4 and second["policy_version"] == 4
    assert second["env_steps"] >= first["env_steps"] + 2 * cfg.steps_per_iteration
    log = (tmp_path / "reach-tiny" / "log.txt").read_text()
    assert "resumed" in log and "iter     3" in log
    assert int(second["sampler"]["meta"]["last_tick"]) == 4  # the sampler state came back and kept ticking
    # Training time adds up over sessions (the learning curve's wall time).
    assert 0 < first["train_seconds"] < second["train_seconds"]


def test_resume_never_refuses_to_overwrite(tmp_path, capsys):
    cfg = _tiny(tmp_path, mode="serial", max_iterations=1)
    assert train(cfg) == 0
    try:
        train(dataclasses.replace(cfg, resume="never"))
    except SystemExit as exc:
        assert exc.code == 2 and "already has checkpoints" in capsys.readouterr().err
    else:
        raise AssertionError("resume=never overwrote a run")


def _cli(*args: str, **kw) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "RAY_ADDRESS": ""}
    env.pop("RAY_ADDRESS")
    return subprocess.Popen([sys.executable, "-m", "learner.main", *args], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw)


def test_cli_local_mode_leaves_config_checkpoint_log_and_vm_map(tmp_path):
    proc = _cli("--preset", "reach-tiny", "--mode", "local", "--runs-dir", str(tmp_path),
                "--max-iterations", "3", "--total-env-steps", "1000000")
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, out
    run = tmp_path / "reach-tiny"
    assert "starting a private local Ray instance" in out
    assert "iter     3" in out and "steps/s" in out and "eta" in out
    cfg = RunConfig.from_json((run / "config.json").read_text())
    assert cfg.mode == "local" and cfg.name == "reach-tiny"
    assert checkpoint.list_checkpoints(run / "ckpt")
    assert "iter     3" in (run / "log.txt").read_text()
    assert list((run / "tb").glob("events.out.tfevents.*"))
    assert (run / "sampler_vm.png").stat().st_size > 1000
    actors = json.loads((run / "actors.json").read_text())
    assert len(actors) == 2 and all(a["env_steps"] > 0 for a in actors)


def test_sigterm_in_local_mode_checkpoints_exits_zero_and_leaves_no_process(tmp_path):
    proc = _cli("--preset", "reach-tiny", "--mode", "local", "--runs-dir", str(tmp_path),
                "--total-env-steps", "100000000", "--checkpoint-every", "1000")
    lines = []
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if line.startswith("iter     2"):
            break
    children = descendants(proc.pid)  # pid: start time
    assert children, "local mode should have started Ray processes"
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=90)
    assert proc.returncode == 0, "".join(lines) + out
    assert "stopped by signal" in out
    path, state = checkpoint.load_latest(tmp_path / "reach-tiny" / "ckpt")
    assert state["iteration"] >= 2
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and alive(children):  # NOTE: not a zombie, not a reused pid
        time.sleep(0.5)
    left = alive(children)
    assert not left, f"processes left behind: {left}"


def test_bad_config_gets_a_clear_error(tmp_path):
    proc = _cli("--preset", "reach-tiny", "--runs-dir", str(tmp_path), "--steps-per-iteration", "0")
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "--steps-per-iteration = 0 is not allowed: give an integer >= 1" in out
    proc = _cli("--preset", "nope")
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode != 0 and "reach-tiny" in out
    proc = _cli("--preset", "reach-tiny", "--runs-dir", str(tmp_path), "--resume", str(tmp_path / "missing"))
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode != 0 and "cannot be read" in out and "Traceback" not in out


def test_bad_executor_options_exit_2_naming_the_value_and_make_no_run_folder(tmp_path):
    for args, says in [(("--task.executor.clips", "nope"), "clips ['nope'] do not play on the humanoid"),
                       (("--task.executor.reference-cache", "0"),
                        "reference-cache = 0 is not allowed: give an integer in [1, 65536]"),
                       (("--task.executor.catch-up-steps", "-1"), "catch-up-steps = -1 is not allowed: give an integer >= 0")]:
        proc = _cli("--preset", "executor-tiny", "--mode", "serial", "--runs-dir", str(tmp_path), *args)
        out, _ = proc.communicate(timeout=120)
        assert proc.returncode == 2 and says in out and "Traceback" not in out, out
    assert not any(tmp_path.iterdir())


def test_bad_ppo_and_variance_options_name_the_value():
    from common.policy import PolicyConfig
    from learner.ppo import PPOConfig

    import pytest

    with pytest.raises(ValueError, match=r"--ppo.kl-stop = -0.1 is not allowed: give a finite number >= 0"):
        RunConfig(ppo=PPOConfig(kl_stop=-0.1))
    with pytest.raises(ValueError, match=r"--policy.log-std-anneal-steps = -5 is not allowed: give an integer >= 0"):
        RunConfig(policy=PolicyConfig(log_std_anneal_steps=-5))
    from common.tasks.body_config import BodyConfig

    with pytest.raises(ValueError, match=r"--task.body.shape-box-scale = 0.0 is not allowed: give a finite number in \(0, 1\]"):
        BodyConfig(shape_box_scale=0.0)


def test_adaptive_clip_sampling_counts_the_executors_segments_end_to_end(tmp_path):
    """`--sampler.clip-k`: the environments' clip segments travel in the unrolls to the learner,
    with its value report to the sampler, and reweight the balancer; the counts are in the
    checkpoint's sampler state and the draws a restored sampler makes follow them."""
    from common.tasks.executor.env import labelled_clips
    from sampler.shape_sampler import ShapeSampler, state_from_torch

    base = PRESETS["executor-tiny"][1]
    cfg = dataclasses.replace(base, runs_dir=str(tmp_path), quiet=True, mode="serial", max_iterations=3,
                              total_env_steps=10**6, sampler=dataclasses.replace(base.sampler, clip_k=3.0))
    assert train(cfg) == 0
    state = checkpoint.load_latest(tmp_path / "executor-tiny" / "ckpt")[1]
    sampler_state = state_from_torch(state["sampler"])
    meta, arrays = sampler_state["meta"]["clips"], sampler_state["arrays"]
    assert meta["seen"] > 0 and arrays["clips/segments"].sum() > 0
    assert (arrays["clips/tracked"] <= arrays["clips/segments"]).all()
    restored = ShapeSampler(cfg.sampler, make_env(cfg.task).space, labelled_clips(cfg.task))
    restored.load_state_dict(sampler_state)
    b = restored.balancer
    assert not np.allclose(b.draw_probabilities, b.probabilities)  # reweighted by what was seen
    rate = restored.clip_outcomes.tracked_rate
    ratio = b.draw_probabilities / b.probabilities
    assert np.argmax(ratio) == np.argmin(rate)  # the clip tracked least is favoured most
    log = (tmp_path / "executor-tiny" / "log.txt").read_text()
    assert "clips/tracked_pct" in log
