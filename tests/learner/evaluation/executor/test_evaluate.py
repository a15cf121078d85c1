"""Per-clip executor evaluation (learner/evaluation/executor/evaluate.py): start frames, split tags, --clips
resolution, and that one run with termination off gives what the terminating run gives."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from common.tasks.executor import rewards as rw

from learner import checkpoint

from learner.evaluation.executor import evaluate as xe
from tests.learner.evaluation.executor_checkpoints import tiny_executor


@pytest.fixture(scope="module")
def loaded(tmp_path_factory) -> checkpoint.Loaded:
    return checkpoint.load_trained(tiny_executor(tmp_path_factory.mktemp("ckpt")))


def test_start_times_are_evenly_spread_over_the_first_80_percent() -> None:
    assert xe.start_times(2.0, 1) == [0.0]
    np.testing.assert_allclose(xe.start_times(2.0, 5), [0.0, 0.4, 0.8, 1.2, 1.6])
    assert xe.start_times(2.0, 5) == xe.start_times(2.0, 5)
    with pytest.raises(ValueError, match="starts = 0"):
        xe.start_times(2.0, 0)


def test_split_tags_follow_the_checkpoints_config(loaded) -> None:
    from common.tasks.executor.env import humanoid_clips, labelled_clips

    tags = xe.split_tags(loaded.cfg.task)
    assert set(tags) == {c for c, _ in humanoid_clips(mirror=True)}
    trained = {c for c, _ in labelled_clips(loaded.cfg.task)}
    assert {c for c, t in tags.items() if t == "train"} == trained
    plain = {c: t for c, t in tags.items() if not c.endswith("~mirror")}
    assert "test" in plain.values() and "unused" not in plain.values()
    # Trained without mirror images: every mirror image is unused, and default_clips leaves them out.
    assert {t for c, t in tags.items() if c.endswith("~mirror")} == {"unused"}
    assert not any(c.clip_id.endswith("~mirror") for c in xe.default_clips(loaded.cfg.task))
    # Trained with them: each mirror image is on its source's side of the split.
    mirrored = dataclasses.replace(loaded.cfg.task, executor=dataclasses.replace(loaded.cfg.task.executor, mirror=True))
    tags = xe.split_tags(mirrored)
    assert all(tags[c + "~mirror"] == t for c, t in plain.items())
    assert len(xe.default_clips(mirrored)) == 2 * len(plain)
    # A checkpoint trained on a clip list: those are "train"; other train-split clips are "unused".
    listed = dataclasses.replace(loaded.cfg.task, executor=dataclasses.replace(loaded.cfg.task.executor,
                                                                               clips=("humanoid3d_walk",)))
    tags = xe.split_tags(listed)
    assert [c for c, t in tags.items() if t == "train"] == ["humanoid3d_walk"]
    assert "unused" in tags.values() and "test" in tags.values()


@pytest.mark.parametrize("value, says", [
    ("humanoid3d_nope", "'humanoid3d_nope' is no humanoid clip id"),
    ("missing/clip.npz", "file 'missing/clip.npz' does not exist"),
])
def test_unknown_clip_values_are_named(value: str, says: str) -> None:
    with pytest.raises(xe.ClipSelectionError, match=says):
        xe.classify_clip_value(value)


def test_a_folder_without_clips_is_named(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("no clips here")
    with pytest.raises(xe.ClipSelectionError, match=f"folder '{tmp_path}' holds no .npz clips"):
        xe.classify_clip_value(str(tmp_path))


def test_resolve_clips_imports_a_folder_and_keeps_ids_tags(loaded, tmp_path: Path) -> None:
    from common.motion.errors import ClipError
    from common.motion.library import MotionLibrary

    lib = MotionLibrary()
    lib.clip("humanoid3d_walk").save(tmp_path / "mine" / "walk.npz")
    clips = xe.resolve_clips([str(tmp_path / "mine"), "humanoid3d_run", "humanoid3d_run"], loaded.cfg.task)
    assert [(c.clip_id, c.split) for c in clips] == [("imported/walk", "imported"), ("humanoid3d_run", "test")]
    assert clips[0].clip is not None and clips[0].source == str(tmp_path / "mine" / "walk.npz")
    lib.clip("mass/walk").save(tmp_path / "biped.npz")
    with pytest.raises(ClipError, match="for the 'biped' character, not 'humanoid'"):
        xe.resolve_clips([str(tmp_path / "biped.npz")], loaded.cfg.task)


def test_one_run_without_termination_matches_the_terminating_run(loaded) -> None:
    """The evaluation reads the checkpoint's own termination off a run with termination off:
    the environment with termination on ends the same episode at that step, with that return."""
    from common.tasks.registry import make_env

    env = xe.make_eval_env(loaded, [])
    policy = checkpoint.make_policy(loaded, env.obs_dim, env.act_dim)
    rec = xe.run_episode(env, policy, "humanoid3d_kick", 0.3, "per_term", seed=0)
    assert rec["steps"] == rec["planned_steps"] > 10  # termination off: played to the clip's end
    assert not rec["success"] and not rec["pose_success"]  # an untrained policy fails early
    # the checkpoint's own rule watches the pose terms (the presets' terminate_on): never before the five-term rule
    assert loaded.cfg.task.executor.terminate_on == rw.POSE_TERMS
    assert rec["fail_step"] <= rec["own_end_step"]

    task = dataclasses.replace(loaded.cfg.task, episode_s=xe.EVAL_EPISODE_S, executor=dataclasses.replace(
        loaded.cfg.task.executor, clips=(), split="all", at_clip_end="stop", reactive_init=False, catch_up_steps=0))
    live = make_env(task, seed=0)
    obs, _ = live.reset(0, live.space.default_array, clip_id="humanoid3d_kick", start_s=0.3)
    ret, k = 0.0, 0
    while True:
        action, _ = policy.act(obs[None], deterministic=True)
        obs, r, term, trunc, info = live.step(action[0])
        ret, k = ret + r, k + 1
        if term or trunc:
            break
    assert term and k == rec["own_end_step"] and info["ended_by"] in rw.POSE_TERMS
    assert ret == pytest.approx(rec["return"], rel=1e-9)


def test_summary_groups_by_clip_class_and_split() -> None:
    clips = [xe.EvalClip("a", "root/x", "train"), xe.EvalClip("b", "root/y", "test")]
    base = {"planned_steps": 10, "steps": 10, "phc_success": True, "fail_step": None, "failed_term": None,
            "diverged": False, "tracked_frac": 1.0, "return": 5.0, "return_per_planned_step": 0.5,
            "reward_per_step": 0.5, "mpjpe_mm": 20.0, "global_mpe_mm": 30.0}
    recs = [{**base, "clip_id": "a", "label": "root/x", "split": "train", "success": True},
            {**base, "clip_id": "a", "label": "root/x", "split": "train", "success": False, "failed_term": "root_rotation",
             "mpjpe_mm": 40.0},
            {**base, "clip_id": "b", "label": "root/y", "split": "test", "success": False, "phc_success": False,
             "failed_term": "joint_position"}]
    s = xe.summarize(recs, clips)
    assert s["splits"]["train"]["success_pct"] == 50.0 and s["splits"]["test"]["success_pct"] == 0.0
    assert s["overall"]["success_pct"] == pytest.approx(100 / 3) and s["overall"]["phc_success_pct"] == pytest.approx(200 / 3)
    assert s["clips"]["a"]["mpjpe_mm"] == 30.0 and s["clips"]["a"]["mpjpe_mm_success"] == 20.0
    assert s["clips"]["b"]["failed_terms"] == {"joint_position": 1} and s["clips"]["b"]["split"] == "test"
    assert list(s["classes"]) == ["root/x", "root/y"]


def test_summary_groups_labelled_takes_by_content_and_style_per_split() -> None:
    from learner.evaluation.executor import report

    base = {"planned_steps": 10, "steps": 10, "phc_success": True, "fail_step": None, "failed_term": None,
            "diverged": False, "tracked_frac": 1.0, "return": 5.0, "return_per_planned_step": 0.5,
            "reward_per_step": 0.5, "mpjpe_mm": 20.0, "global_mpe_mm": 30.0}
    takes = [("w1", "root/bandai/walk/angry", "train", True), ("w2", "root/bandai/walk/happy", "train", False),
             ("w3", "root/bandai/walk/angry", "test", False), ("r1", "root/bandai/run/angry", "train", True),
             ("k", "root/acrobatics/kick", "train", True)]
    clips = [xe.EvalClip(c, label, split) for c, label, split, _ in takes]
    recs = [{**base, "clip_id": c, "label": label, "split": split, "success": ok} for c, label, split, ok in takes]
    s = xe.summarize(recs, clips)
    assert list(s["contents"]) == ["run", "walk"] and list(s["styles"]) == ["angry", "happy"]
    assert s["contents"]["walk"]["train"]["success_pct"] == 50.0 and s["contents"]["walk"]["test"]["success_pct"] == 0.0
    assert s["styles"]["angry"]["train"]["episodes"] == 2 and s["styles"]["angry"]["train"]["success_pct"] == 100.0
    assert "test" not in s["styles"]["happy"]  # the kick's label is not two-level: in no style row
    lines = report.label_level_table("style", s["styles"])
    assert lines[0].startswith("## By style") and "| `happy` | 1 | 0.0 | 100.0 | 20.0 | - | - | - | - |" in lines
    assert report.label_level_table("style", {}) == []


def test_a_library_evaluation_draws_a_content_by_style_map_and_an_unnamed_clip_profile(tmp_path) -> None:
    from learner.evaluation.executor import report

    base = {"planned_steps": 10, "steps": 10, "phc_success": True, "fail_step": None, "failed_term": None,
            "diverged": False, "tracked_frac": 1.0, "return": 5.0, "return_per_planned_step": 0.5,
            "reward_per_step": 0.5, "mpjpe_mm": 20.0, "global_mpe_mm": 30.0}
    recs = [{**base, "clip_id": f"t{k}", "label": f"root/bandai/{'walk' if k % 2 else 'run'}/s{k % 5}",
             "split": "test" if k % 7 == 0 else "train", "success": k % 3 == 0} for k in range(report.MAX_NAMED_CLIPS + 5)]
    clips = [xe.EvalClip(r["clip_id"], r["label"], r["split"]) for r in recs]
    summary = xe.summarize(recs, clips)
    for png in (report.plot_clips(summary, tmp_path / "clips.png"), report.plot_styles(recs, tmp_path / "styles.png")):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert report.plot_styles([{**recs[0], "label": "root/acrobatics/kick"}], tmp_path / "none.png") is None
    assert not (tmp_path / "none.png").exists()
