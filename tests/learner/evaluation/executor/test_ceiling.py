"""The zero-action ceiling of `morphmimic evaluate` on an executor (starts that fail within 3
control steps with zero actions) and the reference-cleaning fields `--set` may change."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from learner import checkpoint
from learner.evaluation import harness
from learner.evaluation.executor import evaluate as xe
from tests.learner.evaluation.executor_checkpoints import tiny_executor


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    return tiny_executor(tmp_path_factory.mktemp("ckpt"), actuation="pd")


def test_ceiling_counts_the_starts_zero_actions_lose_within_three_steps(run_dir: Path) -> None:
    loaded = checkpoint.load_trained(run_dir)
    clips = xe.resolve_clips(["humanoid3d_backflip", "humanoid3d_walk"], loaded.cfg.task)
    c = xe.zero_action_ceiling(loaded, clips, 3)
    env = xe.make_eval_env(loaded, clips)
    durations = xe.clip_durations(env, clips)
    bad = []
    for i, clip_id, start in xe.episode_jobs(clips, durations, 3):
        r = xe.run_episode(env, harness.ZeroPolicy(env.act_dim), clip_id, start, "per_term", seed=i, max_steps=3)
        assert r["steps"] <= 3
        if r["fail_step"] is not None:
            bad.append((clip_id, start))
    assert c["episodes"] == 6 and c["failed"] == len(bad) and c["starts"] == bad
    assert c["ceiling_pct"] == pytest.approx(100.0 * (6 - len(bad)) / 6)
    assert c["by_split"]["train"]["episodes"] + c["by_split"].get("test", {"episodes": 0})["episodes"] == 6


def test_evaluate_reports_the_ceiling_and_takes_the_cleaning_fields(run_dir: Path, tmp_path: Path, capsys) -> None:
    from learner.evaluation import evaluate

    argv = ["--checkpoint", str(run_dir), "--clips", "humanoid3d_walk", "--starts", "2", "--no-render",
            "--set", "reference_filter_hz=7", "reference_floor=true", "pd_target_range=widened", "--out", str(tmp_path)]
    assert evaluate.main(argv) == 0
    assert "zero-action ceiling:" in capsys.readouterr().out
    res = json.loads((tmp_path / "results.json").read_text())
    assert res["summary"]["zero_action_ceiling"]["episodes"] == 2
    assert "policy_success_on_failed" in res["summary"]["zero_action_ceiling"]
    assert "**Zero-action ceiling**" in (tmp_path / "summary.md").read_text()
    loaded = checkpoint.load_trained(run_dir)
    moved = xe.with_settings(loaded, ["reference_filter_hz=7", "reference_floor=true", "pd_target_range=widened"])
    assert moved.cfg.task.executor == dataclasses.replace(loaded.cfg.task.executor, reference_filter_hz=7.0,
                                                          reference_floor=True, pd_target_range="widened")


def test_pd_target_range_is_refused_on_a_torque_checkpoint(tmp_path: Path) -> None:
    loaded = checkpoint.load_trained(tiny_executor(tmp_path))
    if loaded.cfg.task.executor.actuation != "torque":
        pytest.skip("the tiny preset is not torque")
    with pytest.raises(ValueError, match="only acts on pd actuation"):
        xe.with_settings(loaded, ["pd_target_range=widened"])
