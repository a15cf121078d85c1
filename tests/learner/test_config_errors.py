"""Bad values on the command line and in configs: one line naming the value and what is
allowed, exit code 2, and no run folder (issue 22, item 1)."""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
import typing
from pathlib import Path

import pytest

from common.config_limits import unlimited_numeric_fields
from learner import main as learner_main
from learner.config import RunConfig

ROOT = Path(__file__).resolve().parents[2]


def _config_classes(cls: type) -> list[type]:
    out = [cls]
    for name, hint in typing.get_type_hints(cls).items():
        if dataclasses.is_dataclass(hint):
            out += _config_classes(hint)
    return out


def test_every_numeric_field_of_the_run_config_has_a_limit() -> None:
    missing = {c.__name__: unlimited_numeric_fields(c) for c in _config_classes(RunConfig)}
    assert not {k: v for k, v in missing.items() if v}, missing


@pytest.mark.parametrize("args, says", [
    (["--ppo.lr", "-1e-3"], "--ppo.lr = -0.001 is not allowed: give a finite number in [0, 1]"),
    (["--ppo.gamma", "1.5"], "--ppo.gamma = 1.5 is not allowed: give a finite number in (0, 1]"),
    (["--ppo.lr", "nan"], "--ppo.lr = nan is not allowed"),
    (["--ppo.lr", "2"], "--ppo.lr = 2.0 is not allowed"),
    (["--actors.num-actors", "0"], "--actors.num-actors = 0 is not allowed: give an integer in [1, 4096]"),
    (["--actors.envs-per-actor", "-3"], "--actors.envs-per-actor = -3 is not allowed"),
    (["--sampler.vbar-rate", "0"], "--sampler.vbar-rate = 0.0 is not allowed: give a finite number in (0, 1]"),
    (["--task.sim-hz", "inf"], "--task.sim-hz = inf is not allowed"),
    (["--policy.hidden", "64", "0"], "--policy.hidden = (64, 0) is not allowed: give each an integer >= 1"),
    (["--port-base", "70000"], "--port-base = 70000 is not allowed: give an integer in [0, 65532]"),
    (["--preset", "executor-tiny", "--task.executor.tau", "0"], "--task.executor.tau = 0 is not allowed"),
    (["--preset", "executor-tiny", "--task.executor.split-seed", "1" + "0" * 400], "--task.executor.split-seed = 1000"),
    (["--preset", "lower_biped-tiny", "--task.imitate.speed-range", "2", "1"], "speed-range = (2.0, 1.0) must be low <= high"),
    (["--ppo.lr", "abc"], "--ppo.lr: could not convert string to float: 'abc'; expected: --ppo.lr FLOAT"),
    (["--ppo.lrr", "1"], "Unrecognized options: --ppo.lrr"),
    (["--preset", "nope"], "--preset 'nope' is unknown"),
    (["--preset", "fish", "--task.imitate.swimmer-speed", "stroke_fit"], "fish.json not found: make it with `morphmimic stroke-fit fish`"),
    (["--preset", "lower_biped-tiny", "--task.imitate.swimmer-speed", "stroke_fit"], "'lower_biped' is not a swimmer"),
    (["--preset", "lower_biped-tiny", "--task.imitate.observe-course"], "'lower_biped' is not a swimmer; only a swimmer has a course"),
    (["--preset", "manta", "--task.imitate.swimmer-speed", "fast"], "--task.imitate.swimmer-speed = 'fast': give length, stroke_fit"),
    (["--preset", "lower_biped-tiny", "--sampler.plot-params", "global_z", "Femur_x"],
     "--sampler.plot-params ['global_z', 'Femur_x']: choose two different names from ['global_x'"),
    (["--preset", "lower_biped-tiny", "--sampler.plot-params", "global_z"], "--sampler.plot-params ['global_z']: choose two different names from ['global_x'"),
])
def test_a_bad_value_is_one_line_naming_it_and_exit_2(args, says, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        learner_main.parse(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert says in err, err
    assert len(err.strip().splitlines()) == 1, err


def _run(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "learner.main", "--runs-dir", str(tmp / "runs"), "--mode", "serial", *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_a_checkpoint_that_is_not_one_or_not_this_tasks_makes_no_run_folder(tmp_path: Path) -> None:
    not_a_checkpoint = tmp_path / "notes.txt"
    not_a_checkpoint.write_text("hello")
    cases = [
        (("--resume", str(not_a_checkpoint)), f"checkpoint {not_a_checkpoint} cannot be read"),
        (("--resume", str(tmp_path / "missing")), "cannot be read"),
        (("--resume", str(ROOT / "learner" / "pretrained" / "executor")), "does not fit preset/task 'reach'"),
        (("--ppo.gamma", "2"), "--ppo.gamma = 2.0 is not allowed"),
    ]
    for args, says in cases:
        out = _run(tmp_path, *args)
        assert out.returncode == 2, (args, out.stderr[-2000:])
        assert says in out.stderr and "Traceback" not in out.stderr, out.stderr
        assert len(out.stderr.strip().splitlines()) == 1, out.stderr
        assert not (tmp_path / "runs").exists(), f"{args} created a run folder"


def test_a_saved_config_with_a_bad_value_is_refused_by_name() -> None:
    import json

    text = RunConfig().to_json().replace('"lr": 0.0003', '"lr": -1.0')
    with pytest.raises(ValueError, match=r"--ppo.lr = -1.0 is not allowed"):
        RunConfig.from_json(text)
    raw = json.loads(RunConfig().to_json())
    raw["task"]["executor"]["rsis_frames"] = [1, 2, 3]
    with pytest.raises(ValueError, match=re.escape("--task.executor.rsis-frames = (1, 2, 3) is not allowed: give two")):
        RunConfig.from_json(json.dumps(raw))


@pytest.mark.parametrize("edit", [
    lambda c: c.update(name=5),
    lambda c: c["ppo"].update(lr="abc"),
    lambda c: c.update(task=5),
    lambda c: c["policy"].update(hidden="wide"),
    lambda c: c["actors"].update(num_actors=[2]),
])
def test_a_saved_config_of_the_wrong_type_is_a_value_error_naming_it(edit) -> None:
    import json

    raw = json.loads(RunConfig().to_json())
    edit(raw)
    with pytest.raises(ValueError):
        RunConfig.from_json(json.dumps(raw))
    with pytest.raises(ValueError, match="expected a JSON object"):
        RunConfig.from_json("[1, 2]")


@pytest.mark.parametrize("section, field, bad", [
    ("executor", "catch_up_ends", "soon"), ("executor", "actuation", 3), (None, "mode", ["serial"]),
    ("executor", "mirror", "yes"), ("executor", "reactive_init", 1),
])
def test_a_saved_config_with_a_choice_it_does_not_offer_is_refused_by_name(section, field, bad) -> None:
    import json

    raw = json.loads(RunConfig().to_json())
    where = raw if section is None else raw["task"][section]
    where[field] = bad
    flag = ("--" if section is None else f"--task.{section}.") + field.replace("_", "-")
    with pytest.raises(ValueError, match=rf"{re.escape(flag)} = .* is not one of"):
        RunConfig.from_json(json.dumps(raw))


def test_a_saved_config_with_the_flat_retargeting_fields_loads_them_nested() -> None:
    """An `imitate` section (or, older, a flat task section) written before `ImitateConfig`
    nested a `RetargetConfig` keeps its root-height rule and clearance."""
    raw = json.loads(RunConfig().to_json())
    del raw["task"]["imitate"]["retarget"]
    raw["task"]["imitate"].update(retarget_root_height="contact_smooth", retarget_body_clearance_m=0.01)
    r = RunConfig.from_json(json.dumps(raw)).task.imitate.retarget
    assert (r.root_height, r.body_clearance_m) == ("contact_smooth", 0.01)
    flat = json.loads(RunConfig().to_json())
    del flat["task"]["imitate"]
    flat["task"].update(retarget_root_height="foot_tracks", shin_contact_is_fall=False)
    cfg = RunConfig.from_json(json.dumps(flat))
    assert cfg.task.imitate.retarget.root_height == "foot_tracks" and not cfg.task.imitate.shin_contact_is_fall
