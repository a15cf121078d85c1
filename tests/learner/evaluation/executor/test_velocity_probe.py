"""`morphmimic velocity-probe` (learner/evaluation/executor/velocity_probe.py) on an untrained executor."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.learner.evaluation.executor_checkpoints import tiny_executor


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    return tiny_executor(tmp_path_factory.mktemp("ckpt"))


def test_probe_writes_the_table_and_leaving_joints_out_never_lowers_success(run_dir: Path, tmp_path: Path) -> None:
    from learner.evaluation.executor import velocity_probe

    out = tmp_path / "probe"
    argv = ["--checkpoint", str(run_dir), "--starts", "1", "--splits", "test", "--leave-out", "ankle", "knee", "--out", str(out)]
    assert velocity_probe.main(argv) == 0
    res = json.loads((out / "velocity_probe.json").read_text())["splits"]["test"]
    assert res["episodes"] == 8  # the test split's 8 clips, one start each
    assert res["success_pct"] <= res["pose_success_pct"]
    assert res["success_pct"] <= res["success_left_out_pct"] <= res["pose_success_pct"]
    # an untrained policy breaks the velocity term in most episodes; the shares are of its error then
    assert res["breaks"] >= 4
    assert sum(res["joint_share_pct"].values()) == pytest.approx(100.0)
    assert "| test | 8 |" in (out / "velocity_probe.md").read_text()


def test_a_joint_that_does_not_exist_is_a_usage_error(run_dir: Path, capsys) -> None:
    from learner.evaluation.executor import velocity_probe

    with pytest.raises(SystemExit) as exc:
        velocity_probe.main(["--checkpoint", str(run_dir), "--leave-out", "tail"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "'tail' matches no joint" in err and "right_ankle" in err


def test_left_out_mask_matches_by_part_of_the_name() -> None:
    from learner.evaluation.executor.velocity_probe import left_out_mask

    mask = left_out_mask(["neck", "right_ankle", "right_ankle", "left_ankle", "left_knee"], ["ankle"])
    assert mask.tolist() == [False, True, True, True, False]


def test_the_left_out_error_is_split_by_contact_over_every_step(run_dir: Path) -> None:
    """Every step counts each left-out DOF once, on the floor or free, and the two sums add up to
    the whole squared error of those DOF (recomputed here step by step)."""
    import numpy as np

    from learner import checkpoint

    from learner.evaluation.executor import evaluate as xe
    from learner.evaluation.executor.velocity_probe import EpisodeProbe, joint_of_dof, left_out_mask

    loaded = checkpoint.load_trained(run_dir)
    env = xe.make_eval_env(loaded, xe.resolve_clips(["humanoid3d_walk"], loaded.cfg.task))
    mask = left_out_mask(joint_of_dof(env.ref_model), ["ankle"])
    probe, total, steps = EpisodeProbe(env, mask), [0.0], [0]

    def hook(env, k: int) -> None:
        probe(env, k)
        total[0] += float(np.sum((env.data.qvel[6 : env.nv] - env.scheduler.frame(0).qvel[6:])[mask] ** 2))
        steps[0] += 1

    xe.run_episode(env, checkpoint.make_policy(loaded, env.obs_dim, env.act_dim), "humanoid3d_walk", 0.0, "per_term", 0,
                   on_step=hook)
    assert probe.dof_steps[True] + probe.dof_steps[False] == 6 * steps[0] > 0
    assert probe.dof_steps[True] > 0  # the walk puts a foot on the floor
    assert probe.sq_sum[True] + probe.sq_sum[False] == pytest.approx(total[0])


def test_a_bad_setting_is_a_usage_error(run_dir: Path, capsys) -> None:
    from learner.evaluation.executor import velocity_probe

    with pytest.raises(SystemExit) as exc:
        velocity_probe.main(["--checkpoint", str(run_dir), "--set", "arm_armature=-2"])
    assert exc.value.code == 2 and "--task.executor.arm-armature = -2 is not allowed" in capsys.readouterr().err
