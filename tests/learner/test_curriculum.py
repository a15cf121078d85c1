"""`python -m learner.curriculum`: stages parsed and checked, and a real two-stage run of the
tiny lower biped that grows its box, continues one run and skips what is done when repeated."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from learner import checkpoint
from learner.curriculum import Stage, check_stages, main, parse_stage


@pytest.mark.parametrize("text, stage", [("0.25:2M", Stage(0.25, 2_000_000)), ("1:500k", Stage(1.0, 500_000)),
                                         ("0.5:2e6", Stage(0.5, 2_000_000)), (" 0.75 : 12000000 ", Stage(0.75, 12_000_000))])
def test_a_stage_reads_its_box_scale_and_step_count(text, stage):
    assert parse_stage(text) == stage


@pytest.mark.parametrize("text, message", [("0.5", "give S:N"), ("abc:1M", "give S:N"), ("0:1M", "box scale 0 must be in"),
                                           ("1.5:1M", "box scale 1.5 must be in"), ("0.5:0", "step count 0 must be"),
                                           ("0.5:1.5", "step count 1.5 must be"), ("0.5:1..2M", "give S:N")])
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


def test_a_stage_stopped_early_says_how_to_continue_and_starts_no_later_stage(tmp_path: Path, capsys):
    argv = ["--stages", "0.5:2048", "1:3072", "--", "--preset", "lower_biped-tiny", "--name", "curr", "--mode", "serial",
            "--runs-dir", str(tmp_path), "--quiet", "--max-iterations", "1"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "stopped at 1,024 steps; run the same command to continue" in printed and "stage 2/2" not in printed
