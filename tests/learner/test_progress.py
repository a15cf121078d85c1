"""The shared progress bar (`learner.progress`): on a terminal a live bar with the count and the
time left; anywhere else one final line on stderr and nothing while it runs, so piped output
(a real `morphmimic motion import`) stays clean."""

from __future__ import annotations

import io
import os
import pty
import re
import select
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest

from learner.progress import Progress

ROOT = Path(__file__).resolve().parents[2]


def _read_all(fd: int) -> str:
    """What the terminal received so far (bounded: stops once nothing more arrives for 0.2 s)."""
    chunks = []
    for _ in range(1000):
        ready, _, _ = select.select([fd], [], [], 0.2)
        if not ready:
            break
        chunks.append(os.read(fd, 65536))
    return b"".join(chunks).decode("utf-8", "replace")


@pytest.mark.parametrize("size", [(0, 0), (100, 30)], ids=["terminal-of-no-size", "sized-terminal"])
def test_on_a_terminal_a_live_bar_shows_count_and_time_left(size):
    master, slave = pty.openpty()
    if size != (0, 0):
        termios.tcsetwinsize(slave, (size[1], size[0]))
    stream = os.fdopen(slave, "w", buffering=1)
    try:
        with Progress("[test]", 4, "shapes", stream=stream) as bar:
            bar.update()
            time.sleep(0.6)  # past the bar's redraw interval: the next update draws with a rate and so a time left
            bar.update()
            mid = _read_all(master)
            bar.update(2)
        stream.flush()
        end = _read_all(master)
    finally:
        stream.close()
        os.close(master)
    assert "[test]" in mid and re.search(r"2/4 \[\d\d:\d\d<\d\d:\d\d", mid), mid  # elapsed<time left
    assert "4/4" in end and "shapes/s" in end


def test_off_a_terminal_only_one_final_line(capsys):
    stream = io.StringIO()
    with Progress("[test]", 3, "clips", stream=stream) as bar:
        for _ in range(3):
            bar.write("a result line")
            bar.update()
        assert stream.getvalue() == ""  # nothing while it runs
    assert re.fullmatch(r"\[test\] 3/3 clips in \d+s\n", stream.getvalue())
    assert capsys.readouterr().out == "a result line\n" * 3  # results stay on stdout


def test_a_callback_of_several_calls_adds_up_and_the_total_may_grow():
    stream = io.StringIO()
    with Progress("[rows]", 2, "episodes", stream=stream) as bar:
        first, second = bar.callback(0), bar.callback(5)
        first(5, 5)
        second(3, 5)
        bar.set(8, 10)
    assert stream.getvalue().startswith("[rows] 8/10 episodes in ")


def test_piped_motion_import_keeps_stdout_for_results_and_stderr_to_one_line(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "learner.cli", "motion", "import", "--procedural", "--out", str(tmp_path)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout.splitlines()
    assert len(out) == 3 and all(".npz: " in line for line in out), proc.stdout
    assert re.fullmatch(r"\[motion import\] 3/3 clips in \d+s\n", proc.stderr), proc.stderr
