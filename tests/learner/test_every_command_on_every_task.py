"""Every command that takes a checkpoint, on a freshly trained checkpoint of every kind of
registered task (issue 53): `play`, `studio`, `evaluate`, `learning-curve` and `robustness` either
work with that task's own figures and files, or refuse in one line naming the tasks they take
(exit 2, no traceback), as the task registry (`common.tasks.registry.TaskEntry.commands`) says.

One tiny run per kind of task, trained in this process when a case first needs it and kept for
the module (serial mode, two iterations of 256 steps; the executor one, on one clip, since its
learning curve measures every humanoid clip per checkpoint): reach (the arm), lower_biped (a
walker), fish (a swimmer), the executor. The other registered tasks share a trained one's
family, command list and swimmer kind (checked below).
Each command runs through `learner.cli.main`, the `morphmimic` entry function, with options that
keep it short. The studio's screenshots (headless Chromium drawing the page with software WebGL,
18-38 s each on 2 busy cores) of the walker, the swimmer and the executor are `slow`; the default
set keeps reach's, the new one (tests/learner/live/test_studio.py has a walker and the executor in
the page). Measured on 2 cores under a load of 8-13 from other runs: the default set (17 cases
and the registry check) in 42-83 s (33 s of this process's CPU), the 3 slow cases in 89 s."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from common.tasks.registry import TASKS, command_refusal
from common.tasks.shape.presets import SHAPE_TASKS
from learner import cli
from learner.live.chromium import find_chromium
from learner.presets import PRESETS

TRAINED = {"reach": "reach-tiny", "lower_biped": "lower_biped-tiny", "fish": "fish-tiny", "executor": "executor-tiny"}
"""Task -> the preset its module-wide run trains from."""
ITERATIONS = {"reach": 2, "lower_biped": 2, "fish": 2, "executor": 1}
COMMANDS = ("play", "studio", "evaluate", "learning-curve", "robustness")
EXECUTOR_CLIP = "humanoid3d_walk"


def _kind(task: str) -> tuple:
    """What decides how the commands treat a task: its family, its commands, whether it swims."""
    entry = TASKS[task]
    return entry.family, entry.commands, task in SHAPE_TASKS and SHAPE_TASKS[task][2]


class Runs:
    """Task -> the run directory of a tiny run of it (`ITERATIONS` of 256 steps; the executor on
    one clip), trained on first use."""

    def __init__(self, root: Path):
        self.root, self.done = root, {}

    def __getitem__(self, task: str) -> Path:
        if task not in self.done:
            from learner.train import train

            base = PRESETS[TRAINED[task]][1]
            cfg = dataclasses.replace(base, runs_dir=str(self.root), quiet=True, mode="serial",
                                      max_iterations=ITERATIONS[task], steps_per_iteration=256, total_env_steps=10**6,
                                      vm_plot_every=0, ppo=dataclasses.replace(base.ppo, minibatch=min(base.ppo.minibatch, 256)))
            if task == "executor":
                cfg = dataclasses.replace(cfg, task=dataclasses.replace(
                    cfg.task, executor=dataclasses.replace(cfg.task.executor, clips=(EXECUTOR_CLIP,))))
            assert train(cfg) == 0
            run = self.root / cfg.name
            assert len(list((run / "ckpt").glob("*/state.pt"))) == ITERATIONS[task], task
            self.done[task] = run
        return self.done[task]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Runs:
    return Runs(tmp_path_factory.mktemp("runs"))


def argv_for(command: str, task: str, run: Path, out: Path) -> list[str]:
    """The command's arguments on `run`, kept short: few shapes, targets or starts, short episodes."""
    if command == "play":
        return ["play", "--checkpoint", str(run), "--seconds", "0.4", "--fps", "10", "--width", "96", "--height", "72",
                "--out", str(out / "play.mp4")]
    if command == "studio":
        return ["studio", "--checkpoint", str(run), "--port", "0", "--screenshot", str(out / "studio.png"),
                "--screenshot-after", "0", "--screenshot-size", "1024", "640"]
    short = {"reach": ["--targets", "8"], "executor": ["--starts", "1"],
             "shape": ["--shapes", "2", "--episode-s", "0.5"]}[TASKS[task].family]
    if command == "evaluate":
        clips = ["--clips", EXECUTOR_CLIP, "--no-render"] if task == "executor" else []
        return ["evaluate", "--checkpoint", str(run), *short, *clips, "--out", str(out / "eval")]
    if command == "learning-curve":
        return ["learning-curve", "--ckpt-dir", str(run / "ckpt"), *short, "--out", str(out / "curve")]
    return ["robustness", "--checkpoint", str(run), "--rows", "mass", *(short if task != "reach" else []),
            "--out", str(out / "robustness")]


def run_cli(argv: list[str]) -> int:
    """`morphmimic ARGV`'s exit code; a refusal may end it with SystemExit(2) instead of returning 2."""
    try:
        return cli.main(argv)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1


def check_output(command: str, task: str, out: Path, printed: str) -> None:
    """The files and figures `command` writes for `task`'s family."""
    family = TASKS[task].family
    if command == "play":
        import imageio.v3 as iio

        frames = iio.imread(out / "play.mp4", plugin="FFMPEG")
        assert frames.shape == (4, 72, 96, 3) and frames.std() > 5.0, frames.shape
        if family == "reach":
            assert "mm from the target" in printed
    elif command == "studio":
        import imageio.v3 as iio

        img = iio.imread(out / "studio.png")  # saved once the body showed in the 3-D view (`take_screenshot`)
        assert img.shape[1] == 1024 and img.std() > 10.0 and "wrote" in printed
    elif command == "evaluate":
        if family == "reach":
            results = json.loads((out / "eval" / "results.json").read_text())
            assert {"success_pct", "reached_pct", "final_distance_mm"} <= set(results["summary"])
            assert "fall_down_pct" not in results["summary"]  # an arm does not fall
            assert (out / "eval" / "targets.png").stat().st_size > 0
            assert "success" in printed and "within 20 mm" in printed and "fall" not in printed
        elif family == "executor":
            results = json.loads((out / "eval" / "results.json").read_text())
            assert "success_pct" in results["summary"]["overall"]
            assert (out / "eval" / "clips.png").exists()
        else:
            results = json.loads((out / "eval" / "results.json").read_text())
            assert "fall_down_pct" in results["summary"] and (out / "eval" / "map_return.png").exists()
            if SHAPE_TASKS[task][2]:
                assert "swim_upright_pct" in results["summary"] and "swimming: speed error" in printed
    elif command == "learning-curve":
        curve = json.loads((out / "curve" / "curve.json").read_text())
        assert [r["iteration"] for r in curve["rows"]] == list(range(1, ITERATIONS[task] + 1))
        assert (out / "curve" / "curve.png").exists()
        key = {"reach": "success_pct", "executor": "splits", "shape": "fall_down_pct"}[family]
        assert all(key in r for r in curve["rows"]), curve["rows"]
        if family == "shape" and SHAPE_TASKS[task][2]:
            assert "upright" in printed
    else:
        table = json.loads((out / "robustness" / "robustness.json").read_text())
        assert (out / "robustness" / "robustness.md").exists() and "heavy x1.25" in printed
        assert table


def test_every_registered_task_is_like_one_trained_here() -> None:
    """A new task with another family, command list or swimmer kind needs a run of its own here."""
    trained = {_kind(t) for t in TRAINED}
    for task in TASKS:
        assert _kind(task) in trained, f"{task}: train a tiny run of it in TRAINED"


CASES = [pytest.param(task, command, marks=[pytest.mark.slow] if command == "studio" and task != "reach" else [],
                      id=f"{task}-{command}") for task in TRAINED for command in COMMANDS]


@pytest.mark.parametrize("task, command", CASES)
def test_a_command_works_on_the_task_or_refuses_in_one_line(runs, task: str, command: str, tmp_path: Path,
                                                            capsys) -> None:
    refusal = command_refusal(task, command)
    if command == "studio" and refusal is None and find_chromium() is None:
        pytest.skip("chromium is not installed (apt-get install chromium; .ci/run does)")
    code = run_cli(argv_for(command, task, runs[task], tmp_path))
    out, err = capsys.readouterr()
    if refusal is not None:
        assert code == 2
        assert err.strip().splitlines() == [f"morphmimic {command}: {refusal}"], err
        assert "Traceback" not in err + out
        return
    assert code == 0, err[-2000:]
    assert "Traceback" not in err
    check_output(command, task, tmp_path, out)
