"""`learner/pretrained/in-progress/resume.sh`: every run it can start is a command the trainer
accepts (a typo in a flag would only show when a session starts it in the background), and a
name it does not know stops it before anything starts."""

from __future__ import annotations

import re
import shlex
import subprocess
from pathlib import Path

import pytest

from learner import curriculum, main as learner_main

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "learner/pretrained/in-progress/resume.sh"


def _names() -> list[str]:
    block = SCRIPT.read_text().split("declare -A ARGS=(", 1)[1].split("\n)", 1)[0]
    return re.findall(r"^\s*\[([\w.-]+)\]=", block, flags=re.M)


def _dry_run(*names: str) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), "--dry-run", *names], capture_output=True, text=True, timeout=60)


def test_the_script_lists_runs() -> None:
    assert len(_names()) >= 2, _names()


@pytest.mark.parametrize("name", _names())
def test_every_run_is_a_command_the_trainer_accepts(name: str) -> None:
    done = _dry_run(name)
    if done.returncode == 2 and "has no checkpoint" in done.stderr:
        pytest.skip(f"{name}: no checkpoint here to continue ({done.stderr.strip()})")
    assert done.returncode == 0, done.stderr
    argv = shlex.split(done.stdout.strip())
    assert argv[:2] == ["python", "-m"] and argv[argv.index("--name") + 1] == name, argv
    module, args = argv[2], argv[3:]
    if module == "learner.curriculum":
        cut = args.index("--")
        stages = curriculum.check_stages([curriculum.parse_stage(s) for s in args[1:cut]])
        args = args[cut + 1:] + ["--total-env-steps", str(stages[-1].until_steps)]
    else:
        assert module == "learner.main", module
    cfg = learner_main.parse(args)  # SystemExit(2) on an unknown flag or a value out of range
    assert cfg.name == name


def test_an_unknown_run_stops_the_script_before_anything_starts() -> None:
    first = _names()[0]
    done = _dry_run(first, "no-such-run")
    assert done.returncode == 2
    assert "unknown run 'no-such-run'" in done.stderr and first in done.stderr
    assert done.stdout == ""


def test_one_run_takes_the_machine_and_several_share_it() -> None:
    order = SCRIPT.read_text().split("ORDER=(", 1)[1].split(")", 1)[0].split()
    assert order and set(order) <= set(_names()), order
    runnable = [n for n in _names() if _dry_run(n).returncode == 0]
    if len(runnable) < 2:
        pytest.skip("fewer than two runs with a checkpoint here")
    alone = _dry_run(runnable[0]).stdout.split()
    assert alone[alone.index("--mode") + 1] == "local"
    both = [line.split() for line in _dry_run(*runnable[:2]).stdout.splitlines()]
    assert [argv[argv.index("--mode") + 1] for argv in both] == ["serial", "serial"]
