"""`morphmimic evaluate` on an executor checkpoint (learner/evaluation/executor/report.py, reached through
learner/evaluation/evaluate.py) and the executor ablation table (learner/evaluation/executor/ablation.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.learner.evaluation.executor_checkpoints import tiny_executor


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    return tiny_executor(tmp_path_factory.mktemp("ckpt"))


@pytest.mark.render
def test_evaluate_writes_results_summary_chart_and_strips(run_dir: Path, tmp_path: Path, capsys) -> None:
    from learner.evaluation import evaluate

    out = tmp_path / "eval"
    argv = ["--checkpoint", str(run_dir), "--clips", "humanoid3d_walk", "humanoid3d_run", "--starts", "2", "--out", str(out)]
    assert evaluate.main(argv) == 0
    captured = capsys.readouterr()
    assert captured.err.startswith("[evaluate] xtiny 4/4 episodes in ")  # the progress bar's one line off a terminal
    printed = captured.out.splitlines()
    assert [ln.split(":")[0] for ln in printed if "success" in ln] == [
        "[evaluate] xtiny train", "[evaluate] xtiny test", "[evaluate] xtiny all"]
    res = json.loads((out / "results.json").read_text())
    assert set(res) == {"meta", "summary", "episodes"}
    assert res["meta"]["starts"] == 2 and res["meta"]["clips"] == ["humanoid3d_walk", "humanoid3d_run"]
    assert set(res["summary"]) == {"overall", "splits", "classes", "contents", "styles", "clips", "zero_action_ceiling"}
    assert res["summary"]["contents"] == {} and res["summary"]["styles"] == {}  # no two-level labelled take here
    assert set(res["summary"]["splits"]) == {"train", "test"}
    assert len(res["episodes"]) == 4 and {e["start_s"] for e in res["episodes"]} >= {0.0}
    for key in ("success_pct", "phc_success_pct", "mpjpe_mm", "reward_per_step"):
        assert key in res["summary"]["overall"]
    for e in res["episodes"]:
        assert {"success", "phc_success", "mpjpe_mm", "reward_per_step", "split", "label"} <= set(e)
    text = (out / "summary.md").read_text()
    assert "## By split" in text and "## By class" in text and "| `humanoid3d_run` | test |" in text
    for png in ("clips.png", "best.png", "worst.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", png


def test_evaluate_a_folder_of_npz_clips(run_dir: Path, tmp_path: Path) -> None:
    from common.motion.library import MotionLibrary
    from learner.evaluation import evaluate

    MotionLibrary().clip("humanoid3d_run").save(tmp_path / "clips" / "fast.npz")
    out = tmp_path / "eval"
    assert evaluate.main(["--checkpoint", str(run_dir), "--clips", str(tmp_path / "clips"), "--starts", "1",
                          "--out", str(out), "--no-render"]) == 0
    res = json.loads((out / "results.json").read_text())
    assert list(res["summary"]["clips"]) == ["imported/fast"]
    assert res["summary"]["clips"]["imported/fast"]["split"] == "imported"
    assert res["meta"]["sources"] == {"imported/fast": str(tmp_path / "clips" / "fast.npz")}
    assert not (out / "best.png").exists()


def test_zero_action_baseline_runs_the_same_episodes_without_the_policy(run_dir: Path, tmp_path: Path, capsys) -> None:
    import numpy as np

    from learner.evaluation import evaluate, harness
    from learner import checkpoint

    from learner.evaluation.executor import evaluate as xe

    argv = ["--checkpoint", str(run_dir), "--clips", "humanoid3d_walk", "--starts", "2", "--no-render"]
    assert evaluate.main([*argv, "--out", str(tmp_path / "policy")]) == 0
    assert evaluate.main([*argv, "--zero-action"]) == 0  # default --out beside the checkpoint, not over its eval_clips
    printed = capsys.readouterr().out
    assert "[evaluate] xtiny (zero action) train:" in printed
    out = checkpoint.load_trained(run_dir).path.parent / "eval_clips_zero_action"
    zero, policy = (json.loads((d / "results.json").read_text()) for d in (out, tmp_path / "policy"))
    assert zero["meta"]["actions"] == "zero" and policy["meta"]["actions"] == "mean"
    assert "zero actions, not the policy" in (out / "summary.md").read_text()
    assert [e["start_s"] for e in zero["episodes"]] == [e["start_s"] for e in policy["episodes"]]
    # the baseline is the task under zero actions: the same episode rerun by hand with zeros
    loaded = checkpoint.load_trained(run_dir)
    clips = xe.resolve_clips(["humanoid3d_walk"], loaded.cfg.task)
    env = xe.make_eval_env(loaded, clips)
    by_hand = xe.run_episode(env, harness.ZeroPolicy(env.act_dim), "humanoid3d_walk", zero["episodes"][1]["start_s"],
                             loaded.cfg.task.executor.termination, seed=1)
    assert by_hand["return"] == pytest.approx(zero["episodes"][1]["return"])
    assert not np.isclose(zero["episodes"][1]["return"], policy["episodes"][1]["return"])


def test_set_evaluates_the_policy_on_a_changed_body_in_every_worker(run_dir: Path, tmp_path: Path, capsys) -> None:
    """`--set ankle_armature=0.1`: the workers' episodes are the ones an environment built with the
    changed config gives by hand, not the checkpoint's own; the files say what was changed."""
    import dataclasses

    from learner.evaluation import evaluate
    from learner import checkpoint

    from learner.evaluation.executor import evaluate as xe

    argv = ["--checkpoint", str(run_dir), "--clips", "humanoid3d_dance_a", "--starts", "2", "--no-render", "--workers", "2"]
    assert evaluate.main([*argv, "--out", str(tmp_path / "as_trained")]) == 0
    assert evaluate.main([*argv, "--set", "ankle_armature=0.1", "--out", str(tmp_path / "set")]) == 0
    as_trained, changed = (json.loads((tmp_path / d / "results.json").read_text()) for d in ("as_trained", "set"))
    assert changed["meta"]["settings"] == ["ankle_armature=0.1"] and as_trained["meta"]["settings"] == []
    assert "`--set ankle_armature=0.1`" in (tmp_path / "set" / "summary.md").read_text()
    loaded = checkpoint.load_trained(run_dir)
    assert loaded.cfg.task.executor.ankle_armature == 0.01
    moved = xe.with_settings(loaded, ["ankle_armature=0.1"])
    assert moved.cfg.task.executor == dataclasses.replace(loaded.cfg.task.executor, ankle_armature=0.1)
    env = xe.make_eval_env(moved, xe.resolve_clips(["humanoid3d_dance_a"], moved.cfg.task))
    by_hand = xe.run_episode(env, checkpoint.make_policy(moved, env.obs_dim, env.act_dim), "humanoid3d_dance_a",
                             changed["episodes"][1]["start_s"], moved.cfg.task.executor.termination, seed=1)
    assert by_hand["return"] == pytest.approx(changed["episodes"][1]["return"])
    assert by_hand["return"] != pytest.approx(as_trained["episodes"][1]["return"])


@pytest.mark.parametrize("pair, says", [
    ("clips=[]", "--set 'clips=[]': give NAME=VALUE with NAME one of ankle_armature,"),
    ("ankle_armature", "--set 'ankle_armature': give NAME=VALUE"),
    ("ankle_armature=-1", "--task.executor.ankle-armature = -1 is not allowed: give a finite number in [0, 10]"),
    ("target_velocity_window=2.5", "--task.executor.target-velocity-window = 2.5 is not allowed: give an integer in [1, 30]"),
    ("joint_velocity=bogus", "--task.executor.joint-velocity = 'bogus' is not one of instant, step_mean"),
    ("alpha=null", "--task.executor.alpha = None is not allowed: give a finite number in (0, 1)"),
    ("alpha=0", "--task.executor.alpha = 0 is not allowed: give a finite number in (0, 1)"),
    ("target_velocity_window=1" + "0" * 400, "--task.executor.target-velocity-window = 1000"),
    ("alpha=" + "[" * 5000, "--task.executor.alpha = '[[[["),
    ("reward_weights=0,0,0,0,0", "--task.executor.reward-weights = (0, 0, 0, 0, 0): give at least one weight > 0"),
    ("pd_action_scale=2", "pd_action_scale only acts on pd actuation and this checkpoint uses torque, so it would change nothing"),
    ("ankle_armature=true", "--task.executor.ankle-armature = True is not allowed"),
    ("ankle_armature=[1,2]", "--task.executor.ankle-armature = (1, 2) is not allowed: give one value"),
    ("terminate_on=joint_speed", "--task.executor.terminate-on = ('joint_speed',): give one or more distinct terms"),
])
def test_bad_set_is_a_usage_error_naming_the_value(run_dir: Path, tmp_path: Path, pair, says, capsys) -> None:
    from learner.evaluation import evaluate

    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--checkpoint", str(run_dir), "--starts", "1", "--set", pair, "--out", str(tmp_path / "e")])
    assert exc.value.code == 2
    assert says in capsys.readouterr().err
    assert not (tmp_path / "e").exists()


def test_set_refuses_a_name_given_twice(run_dir: Path, capsys) -> None:
    from learner.evaluation import evaluate

    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--checkpoint", str(run_dir), "--set", "alpha=0.2", "alpha=0.3"])
    assert exc.value.code == 2 and "alpha is set twice; give each name once" in capsys.readouterr().err


@pytest.mark.parametrize("option", [["--zero-action"], ["--starts", "3"], ["--clips", "humanoid3d_walk"],
                                    ["--set", "ankle_armature=0.1"], ["--clips-per-shape", "2"]])
def test_executor_options_on_a_shape_checkpoint_are_a_usage_error_naming_them(option, capsys) -> None:
    from learner.evaluation import evaluate

    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--checkpoint", str(Path(__file__).resolve().parents[4] / "learner/pretrained/fish"), *option])
    assert exc.value.code == 2
    assert ("task 'fish' is not the executor; --clips, --starts, --zero-action, --set, --clips-per-shape are executor "
            "options"
            in capsys.readouterr().err)


@pytest.mark.parametrize("bad, says", [
    (["--clips", "humanoid3d_nope"], "--clips: 'humanoid3d_nope' is no humanoid clip id"),
    (["--clips", "no/such/file.npz"], "--clips: file 'no/such/file.npz' does not exist"),
    (["--clips", "{empty}"], "--clips: folder '{empty}' holds no .npz clips"),
    (["--starts", "0"], "--starts = 0 is not allowed: give an integer >= 1"),
])
def test_bad_clips_and_starts_are_usage_errors_naming_the_value(run_dir: Path, tmp_path: Path, bad, says, capsys) -> None:
    from learner.evaluation import evaluate

    empty = tmp_path / "empty"
    empty.mkdir()
    bad = [b.replace("{empty}", str(empty)) for b in bad]
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--checkpoint", str(run_dir), *bad, "--out", str(tmp_path / "e")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert says.replace("{empty}", str(empty)) in err, err
    assert not (tmp_path / "e").exists()


def test_a_clip_for_another_character_is_a_usage_error(run_dir: Path, tmp_path: Path, capsys) -> None:
    from common.motion.library import MotionLibrary
    from learner.evaluation import evaluate

    MotionLibrary().clip("mass/walk").save(tmp_path / "biped.npz")
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--checkpoint", str(run_dir), "--clips", str(tmp_path / "biped.npz"), "--no-render"])
    assert exc.value.code == 2
    assert "is for the 'biped' character, not 'humanoid'" in capsys.readouterr().err


def test_executor_ablation_table_has_one_row_per_arm(tmp_path: Path, capsys) -> None:
    from learner.evaluation import ablation

    torque = tiny_executor(tmp_path, "arm-torque")
    pd = tiny_executor(tmp_path, "arm-pd", actuation="pd", termination="sum", reactive_init=False)
    out = tmp_path / "abl"
    argv = ["--checkpoints", str(torque), str(pd), "--clips", "humanoid3d_walk", "humanoid3d_run", "--starts", "1",
            "--out", str(out)]
    assert ablation.main(argv) == 0
    text = (out / "ablation.md").read_text()
    assert "| `arm-torque` | torque · per-term · balancer · reactive init | 0 |" in text
    assert "| `arm-pd` | pd · sum rule · balancer · no reactive init | 0 |" in text
    rows = json.loads((out / "ablation.json").read_text())
    assert [r["name"] for r in rows] == ["arm-torque", "arm-pd"]
    assert all(set(r["summary"]["splits"]) == {"train", "test"} for r in rows)
    capsys.readouterr()
    assert ablation.main(argv) == 0
    assert capsys.readouterr().out.count("[ablation] reusing") == 2  # same checkpoints, clips and starts


def test_executor_ablation_names_two_checkpoints_of_one_run_by_iteration(tmp_path: Path) -> None:
    """Two checkpoints of one run are two rows told apart by their iteration (as their folders),
    and a share of starts on the frame is named in the settings."""
    from learner import checkpoint
    from learner.evaluation import ablation
    from learner import checkpoint

    run = tiny_executor(tmp_path, "mixed", on_frame_share=0.5)
    state = dict(checkpoint.load_trained(run).state, iteration=5, env_steps=5120)
    checkpoint.save(run / "ckpt", 5, state, keep=5)
    out = tmp_path / "abl"
    assert ablation.main(["--checkpoints", str(run / "ckpt" / "00000000"), str(run / "ckpt" / "00000005"),
                          "--clips", "humanoid3d_walk", "--starts", "1", "--out", str(out)]) == 0
    text = (out / "ablation.md").read_text()
    assert "| `mixed-0` | torque · per-term · balancer · reactive init · 50% of starts on the frame | 0 |" in text
    assert "| `mixed-5` |" in text and "| 5,120 |" in text


def test_ablation_refuses_to_mix_executor_and_shape_checkpoints(tmp_path: Path, capsys) -> None:
    from learner.evaluation import ablation
    from tests.learner.evaluation.test_evaluate import _tiny_checkpoint

    _tiny_checkpoint(tmp_path, "walker")
    arm = tiny_executor(tmp_path, "arm")
    with pytest.raises(SystemExit) as exc:
        ablation.main(["--checkpoints", str(tmp_path / "walker"), str(arm), "--out", str(tmp_path / "abl")])
    assert exc.value.code == 2 and "one ablation compares checkpoints of one family" in capsys.readouterr().err


def test_ablation_settings_name_the_wait_and_the_rotor_inertia_only_when_changed() -> None:
    import dataclasses

    from learner.config import RunConfig
    from learner.evaluation.executor.ablation import settings
    from learner.presets import PRESETS

    preset: RunConfig = PRESETS["executor-pd"][1]
    assert settings(preset) == ("pd · per-term · balancer · reactive init · 50% of starts on the frame · "
                                "rotor inertia ankles 0.1, arms 0.1 kg m^2")
    builders = dataclasses.replace(preset.task.executor, ankle_armature=0.01, arm_armature=0.01, on_frame_share=0.0)
    cfg = dataclasses.replace(preset, task=dataclasses.replace(preset.task, executor=builders))
    assert settings(cfg) == "pd · per-term · balancer · reactive init"
    ex = dataclasses.replace(cfg.task.executor, catch_up_ends="on_track")
    on_track = dataclasses.replace(cfg, task=dataclasses.replace(cfg.task, executor=ex))
    assert settings(on_track) == "pd · per-term · balancer · reactive init · wait ends on track"
    ex = dataclasses.replace(cfg.task.executor, reactive_init=False, catch_up_steps=0, catch_up_ends="on_track")
    no_wait = dataclasses.replace(cfg, task=dataclasses.replace(cfg.task, executor=ex))
    assert settings(no_wait) == "pd · per-term · balancer · no reactive init · no wait"
    ex = dataclasses.replace(cfg.task.executor, ankle_armature=0.1, arm_armature=0.1)
    heavy = dataclasses.replace(cfg, task=dataclasses.replace(cfg.task, executor=ex))
    assert settings(heavy) == "pd · per-term · balancer · reactive init · rotor inertia ankles 0.1, arms 0.1 kg m^2"
