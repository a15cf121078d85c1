"""`morphmimic velocity-probe` (learner/evaluation/velocity_probe.py) on an untrained executor."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.learner.evaluation.executor_checkpoints import tiny_executor


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    return tiny_executor(tmp_path_factory.mktemp("ckpt"))


def test_probe_writes_the_table_and_leaving_joints_out_never_lowers_success(run_dir: Path, tmp_path: Path) -> None:
    from learner.evaluation import velocity_probe

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
    from learner.evaluation import velocity_probe

    with pytest.raises(SystemExit) as exc:
        velocity_probe.main(["--checkpoint", str(run_dir), "--leave-out", "tail"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "'tail' matches no joint" in err and "right_ankle" in err


def test_left_out_mask_matches_by_part_of_the_name() -> None:
    from learner.evaluation.velocity_probe import left_out_mask

    mask = left_out_mask(["neck", "right_ankle", "right_ankle", "left_ankle", "left_knee"], ["ankle"])
    assert mask.tolist() == [False, True, True, True, False]
