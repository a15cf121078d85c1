"""`morphmimic distill`: the torque label is the PD's force averaged over the step on the real
humanoid (an approximation of its step, see learner/distill.py), and a tiny PD executor distils
into a torque checkpoint that the learner resumes; bad input is refused in one line."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from learner import checkpoint
from learner.presets import PRESETS
from tests.learner.evaluation.executor_checkpoints import tiny_executor


def _pair(seed: int = 3, velocity_target: bool = True):
    from common.tasks.executor.env import ExecutorEnv

    preset = PRESETS["executor-pd"][1].task
    pd_task = dataclasses.replace(preset, executor=dataclasses.replace(preset.executor, pd_velocity_target=velocity_target))
    torque_task = dataclasses.replace(pd_task, executor=dataclasses.replace(pd_task.executor, actuation="torque"))
    return ExecutorEnv(torque_task, seed=seed), ExecutorEnv(pd_task, seed=seed)


@pytest.mark.parametrize("velocity_target", [False, True])
def test_the_label_is_the_pd_force_averaged_over_the_step_with_the_passive_damping_given_back(velocity_target: bool):
    """On the real humanoid, from a reset state: the label times the efforts equals the PD
    actuator force averaged over the substeps (run by hand here) plus the torque model's passive
    damping force at each substep's velocity, within the clip; with the PD's target velocity
    (`pd_velocity_target`) its target leads the frame by kd / kp times the frame's joint velocity."""
    import mujoco

    from learner.distill import TorqueLabeler

    torque_env, pd_env = _pair(velocity_target=velocity_target)
    labeler = TorqueLabeler(torque_env, pd_env.model, pd_env.ex.pd_action_scale)
    rng = np.random.default_rng(0)
    for trial in range(3):
        torque_env.reset(trial, torque_env.space.default_array)
        action = rng.normal(0.0, 0.3, torque_env.act_dim)
        frame = torque_env.scheduler.frame(1)
        target = torque_env.layout.to_vector(frame.qpos)
        if velocity_target:  # position actuators: force kp (ctrl - q) - kd qdot
            kp, kd = pd_env.model.actuator_gainprm[:, 0], -pd_env.model.actuator_biasprm[:, 2]
            target = target + kd / kp * frame.qvel[6:]
        u = labeler.label(action)
        d = mujoco.MjData(pd_env.model)
        d.qpos[:], d.qvel[:] = torque_env.data.qpos, torque_env.data.qvel
        d.ctrl[:] = target + pd_env.ex.pd_action_scale * action
        total = np.zeros(torque_env.act_dim)
        for _ in range(torque_env.cfg.substeps):
            damping = torque_env.model.dof_damping[6:] * d.qvel[6:]  # one actuator per DOF, in DOF order
            mujoco.mj_step(pd_env.model, d)
            total += d.actuator_force + damping
        expected = np.clip(total / (torque_env.cfg.substeps * torque_env.efforts), -1.0, 1.0)
        np.testing.assert_allclose(u, expected, atol=1e-9)
        assert np.abs(u).max() > 0.01  # the PD pushes: the label is not the zero it would be without a target


def test_a_tiny_pd_executor_distils_into_a_torque_checkpoint_the_learner_resumes(tmp_path: Path):
    import torch

    from learner.distill import main
    from learner.learner import Learner

    teacher = tiny_executor(tmp_path, "pd", actuation="pd")
    out = tmp_path / "student"
    assert main(["--teacher", str(teacher), "--out", str(out), "--rounds", "2", "--steps", "150", "--epochs", "2"]) == 0
    _, state = checkpoint.load_latest(out / "ckpt")
    teacher_state = checkpoint.load_latest(teacher / "ckpt")[1]
    assert state["env_steps"] == teacher_state["env_steps"] + 300
    from learner.config import RunConfig

    cfg = RunConfig.from_json(state["config"])
    assert cfg.task.executor.actuation == "torque"
    learner = Learner(dataclasses.replace(PRESETS["executor-tiny"][1], name="student"))
    learner.load_state_dict(state)  # what `python -m learner.main --preset executor-tiny --resume` does
    for key in ("normalizer.mean", "normalizer.var"):
        assert torch.equal(state["policy"][key], teacher_state["policy"][key])
    assert torch.equal(state["value"]["net.0.weight"], teacher_state["value"]["net.0.weight"])
    assert not torch.equal(state["policy"]["mean_net.0.weight"], teacher_state["policy"]["mean_net.0.weight"])
    policy_cfg = PRESETS["executor-tiny"][1].policy
    frac = min(1.0, state["env_steps"] / policy_cfg.log_std_anneal_steps)
    expected = policy_cfg.init_log_std + frac * (policy_cfg.final_log_std - policy_cfg.init_log_std)
    assert float(state["policy"]["log_std"].mean()) == pytest.approx(expected)  # where the variance controller stands
    assert cfg.resume == "auto" and cfg.name == "student"


@pytest.mark.parametrize("argv, message", [
    (["--rounds", "0"], "--rounds = 0 is not allowed: give an integer >= 1"),
    (["--lr", "nan"], "--lr = nan is not allowed: give a finite number > 0"),
    (["--steps", "x"], "Error parsing --steps: invalid literal for int() with base 10: 'x'"),
    (["--seed", "-1"], "--seed = -1 is not allowed: give an integer in [0, 4294967295]"),
    (["--seed", str(2**64)], "is not allowed: give an integer in [0, 4294967295]"),
])
def test_bad_options_are_named(tmp_path: Path, argv, message, capsys):
    from learner.distill import main

    with pytest.raises(SystemExit) as exc:
        main(["--teacher", str(tmp_path), "--out", str(tmp_path / "o"), *argv])
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_a_torque_teacher_or_a_used_out_directory_is_refused(tmp_path: Path, capsys):
    from learner.distill import main

    torque = tiny_executor(tmp_path, "torque")
    with pytest.raises(SystemExit) as exc:
        main(["--teacher", str(torque), "--out", str(tmp_path / "o")])
    assert exc.value.code == 2 and "a PD executor checkpoint is needed" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["--teacher", str(torque), "--out", str(torque)])
    assert exc.value.code == 2 and "already holds checkpoints" in capsys.readouterr().err


def test_a_missing_or_foreign_teacher_and_a_file_as_out_are_refused(tmp_path: Path, capsys):
    from learner.distill import main
    from tests.learner.evaluation.test_evaluate import _tiny_checkpoint

    with pytest.raises(SystemExit) as exc:
        main(["--teacher", str(tmp_path / "nothing"), "--out", str(tmp_path / "o")])
    assert exc.value.code == 2 and "--teacher" in capsys.readouterr().err
    _tiny_checkpoint(tmp_path, "walker")
    with pytest.raises(SystemExit) as exc:
        main(["--teacher", str(tmp_path / "walker"), "--out", str(tmp_path / "o")])
    assert exc.value.code == 2 and "a PD executor checkpoint is needed (task 'lower_biped'" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    with pytest.raises(SystemExit) as exc:
        main(["--teacher", str(tmp_path / "walker"), "--out", str(tmp_path / "file")])
    assert exc.value.code == 2 and "is a file" in capsys.readouterr().err
