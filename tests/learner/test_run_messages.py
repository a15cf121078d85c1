"""What `python -m learner.main` says around a run: a new run names the return its preset reaches
when trained; a normal local run prints neither Ray's `E ... core_worker.cc` line nor its token
notice; a finished run says so in one line and exits 0 within seconds without importing Ray."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

from learner.expected_returns import EXPECTED, SMOKE_TESTS, first_run_line
from learner.presets import PRESETS

ROOT = Path(__file__).resolve().parents[2]
RAY_NOISE = (
    re.compile(r"^\[\d{4}-\d\d-\d\d [\d:,]+ E \d+ \d+\]", re.M),  # any error line of Ray's C++ core
    re.compile(r"core_worker\.cc"),
    re.compile(r"Token authentication is enabled"),
    re.compile(r"RAY_AUTH_MODE"),
)


def _env() -> dict[str, str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": str(ROOT)}
    env.pop("RAY_ADDRESS", None)
    env.pop("RAY_AUTH_MODE", None)  # the default a user has
    return env


def test_every_measured_figure_is_a_preset_and_in_its_record():
    assert set(EXPECTED) <= set(PRESETS) and set(SMOKE_TESTS) <= set(PRESETS)
    for preset, m in EXPECTED.items():
        assert m.value in (ROOT / m.source).read_text(), (preset, m.source)
        assert m.kind in ("training", "evaluate")
    for preset in PRESETS:
        line = first_run_line(preset)
        assert "\n" not in line and preset in line
    assert "37.6" in first_run_line("reach") and "no measured return" in first_run_line("fish")


def test_a_local_run_says_its_expected_return_without_ray_noise_and_a_rerun_stops_at_once(tmp_path):
    args = ["--preset", "reach-tiny", "--mode", "local", "--runs-dir", str(tmp_path)]
    first = subprocess.run([sys.executable, "-m", "learner.main", *args], cwd=ROOT, env=_env(),
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
    assert first.returncode == 0, first.stdout
    assert "starting a private local Ray instance" in first.stdout and "step budget reached" in first.stdout
    assert first.stdout.splitlines()[0] == first_run_line("reach-tiny")
    for noise in RAY_NOISE:
        assert not noise.search(first.stdout), (noise.pattern, first.stdout)

    # The same command again: the run has its budget. One line, exit 0, Ray never imported (so no
    # Ray process and no session directory).
    ray_tmp = tmp_path / "ray-tmp"
    probe = ("import sys; from learner.main import main; rc = main(sys.argv[1:]); "
             "print('ray imported' if 'ray' in sys.modules else 'no ray'); raise SystemExit(rc)")
    t0 = time.monotonic()
    again = subprocess.run([sys.executable, "-c", probe, *args], cwd=ROOT, env={**_env(), "RAY_TMPDIR": str(ray_tmp)},
                           capture_output=True, text=True, timeout=120)
    took = time.monotonic() - t0
    assert again.returncode == 0, again.stdout + again.stderr
    lines = again.stdout.splitlines()
    assert len(lines) == 2 and lines[1] == "no ray", again.stdout
    assert lines[0].startswith(f"[morphmimic] run {tmp_path / 'reach-tiny'} is finished (3,072 env steps")
    assert "--total-env-steps" in lines[0] and str(tmp_path / "reach-tiny" / "ckpt" / "00000003") in lines[0]
    assert again.stderr == "" and not ray_tmp.exists()
    assert took < 60, took  # the import of torch and one checkpoint read; a Ray start-up alone takes longer here
