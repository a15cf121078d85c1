"""`morphmimic curriculum`: stages parsed and checked, and a real two-stage run of the
tiny lower biped that grows its box, continues one run and skips what is done when repeated."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from learner import checkpoint
from learner.curriculum import Stage, check_stages, main, parse_stage


@pytest.mark.parametrize("text, stage", [("0.25:2M", Stage(0.25, 2_000_000)), ("1:500k", Stage(1.0, 500_000)),
                                         ("0.5:2e6", Stage(0.5, 2_000_000)), ("1:4.1M", Stage(1.0, 4_100_000)), (" 0.75 : 12000000 ", Stage(0.75, 12_000_000))])
def test_a_stage_reads_its_box_scale_and_step_count(text, stage):
    assert parse_stage(text) == stage


@pytest.mark.parametrize("text, message", [("0.5", "give S:N"), ("abc:1M", "give S:N"), ("0:1M", "box scale 0 must be in"),
                                           ("1.5:1M", "box scale 1.5 must be in"), ("0.5:0", "step count 0 must be"),
                                           ("0.5:1.5", "step count 1.5 must be"), ("0.5:1e20", "must be a whole number from 1"), ("0.5:1..2M", "give S:N")])
def test_a_bad_stage_is_named_with_the_form_allowed(text, message):
    with pytest.raises(ValueError, match=message):
        parse_stage(text)


def test_stages_must_end_in_order():
    with pytest.raises(ValueError, match="must end after the stage before it"):
        check_stages([Stage(0.25, 2_000_000), Stage(0.5, 2_000_000)])


@pytest.mark.parametrize("argv, message", [
    (["--stages", "0.5:1M", "--", "--preset", "lower_biped-tiny", "--total-env-steps", "5"], "--total-env-steps is set by each stage"),
    (["--stages", "0.5:1M", "--", "--preset", "lower_biped-tiny", "--task.body.shape-box-scale=0.5"], "shape-box-scale is set by each stage"),
    (["--stages", "0.5:1M", "--", "--preset", "lower_biped-tiny", "--ppo.lr-schedule", "linear"], "linear decays to zero"),
    (["--stages", "0.5:1M", "--", "--preset", "lower_biped-fixedshape"], "no box to grow"),
    (["--stages", "1:2M", "0.5:1M", "--", "--preset", "lower_biped-tiny"], "must end after"),
    (["--stages", "1:1M", "0.5:2M", "--", "--preset", "lower_biped-tiny"], "shrinks the box"),
    (["--stages", "0.5:1M", "--", "--preset", "lower_biped-tiny", "--max-iterations", "3"], "--max-iterations is set by each stage"),
    (["--stages", "0.5:1M"], "give the run after --"),
    (["--stages", "0.5:1M", "--", "--name", "x"], "give the run after --"),
])
def test_the_command_refuses_what_the_stages_cannot_do(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_two_stages_grow_the_box_in_one_run_and_a_repeat_skips_them(tmp_path: Path, capsys):
    argv = ["--stages", "0.5:1024", "1:2048", "--", "--preset", "lower_biped-tiny", "--name", "curr", "--mode", "serial",
            "--runs-dir", str(tmp_path), "--quiet"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "stage 1/2 (box x0.5 until 1,024 steps): from 0 steps" in printed
    assert "stage 2/2 (box x1 until 2,048 steps): from 1,024 steps" in printed
    path, state = checkpoint.load_latest(tmp_path / "curr" / "ckpt")
    assert state["env_steps"] == 2048
    boxes = {checkpoint.load(p)["env_steps"]: json.loads(checkpoint.load(p)["config"])["task"]["body"]["shape_box_scale"]
             for p in checkpoint.list_checkpoints(tmp_path / "curr" / "ckpt")}
    assert boxes == {1024: 0.5, 2048: 1.0}
    assert main(argv) == 0  # everything done: nothing trains again
    printed = capsys.readouterr().out
    assert "stage 1/2 (box x0.5 until 1,024 steps): done (2,048 steps)" in printed and "stage 2/2" in printed
    assert checkpoint.load_latest(tmp_path / "curr" / "ckpt")[0] == path


def test_a_stage_stopped_by_a_signal_says_how_to_continue_and_starts_no_later_stage(tmp_path: Path, capsys, monkeypatch):
    """A stop request after the first iteration (as Ctrl-C would) ends the command at that
    stage; run again, the command continues the same run from its checkpoint."""
    from learner import train

    real = train.train_until_stop
    monkeypatch.setattr(train, "train_until_stop", lambda cfg: real(cfg, on_iteration=lambda run, m: run.stop.request()))
    argv = ["--stages", "0.5:2048", "1:3072", "--", "--preset", "lower_biped-tiny", "--name", "curr", "--mode", "serial",
            "--runs-dir", str(tmp_path), "--quiet"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "stopped by signal at 1,024 steps; run the same command to continue" in printed and "stage 2/2" not in printed
    monkeypatch.setattr(train, "train_until_stop", real)
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "stage 1/2 (box x0.5 until 2,048 steps): from 1,024 steps" in printed and "all 2 stages done: 3,072 steps" in printed


def test_a_run_trained_as_another_is_not_continued(tmp_path: Path, capsys):
    """A `-uniform` run's checkpoint under the same name is refused before anything trains."""
    base = ["--", "--name", "curr", "--mode", "serial", "--runs-dir", str(tmp_path), "--quiet"]
    assert main(["--stages", "1:1024", *base, "--preset", "lower_biped-tiny"]) == 0
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main(["--stages", "1:2048", *base, "--preset", "lower_biped-tiny", "--sampler.k", "0"])
    assert exc.value.code == 2 and "was trained as another run (sampler.k: checkpoint 1.0, command 0.0)" in capsys.readouterr().err


def test_a_fork_counts_its_stages_from_the_forked_checkpoint(tmp_path: Path, capsys):
    """`--resume PATH` into a new run: stages the forked checkpoint has passed are skipped, the
    first one left starts from it, and the new run then continues its own checkpoints."""
    common = ["--mode", "serial", "--runs-dir", str(tmp_path), "--quiet", "--preset", "lower_biped-tiny"]
    assert main(["--stages", "1:1024", "--", "--name", "parent", *common]) == 0
    parent = checkpoint.load_latest(tmp_path / "parent" / "ckpt")[0]
    capsys.readouterr()
    argv = ["--stages", "0.5:1024", "1:2048", "--", "--name", "fork", "--resume", str(parent), *common]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "stage 1/2 (box x0.5 until 1,024 steps): done (1,024 steps)" in printed
    assert "stage 2/2 (box x1 until 2,048 steps): from 1,024 steps" in printed
    assert checkpoint.load_latest(tmp_path / "fork" / "ckpt")[1]["env_steps"] == 2048
    with pytest.raises(SystemExit) as exc:
        main(["--stages", "1:2048", "--", "--name", "other", "--resume", str(tmp_path / "nothing"), *common])
    assert exc.value.code == 2 and "--resume" in capsys.readouterr().err
