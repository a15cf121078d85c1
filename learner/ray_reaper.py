"""The private local Ray instance dies with the learner: a small watcher process that kills what
is left of the instance's processes as soon as the learner is gone, however it went.

Why: Ray ties most of its processes to the driver that started them, but its dashboard agent
and runtime-env agent outlived a SIGKILLed learner by 60-75 s on main (they report the raylet's
death to the GCS, which is gone too, and wait out the GCS client's timeout), and a learner killed
during `ray.init` would leave everything behind.

How: after `ray.init` starts a private instance, the learner starts this file as its own process
(stdlib only, in its own session so a terminal's Ctrl-C does not reach it) with the instance's
session directory, and holds the write end of a pipe to its stdin. Every `TICK_S` the watcher
notes the instance's processes: those whose `--`-option arguments name the session directory
(GCS, raylet, monitors, agents) and all their descendants (the workers), each with its start
time so a reused pid is never killed. When the pipe reads end-of-file (the learner closed it
after `ray.shutdown`, or the kernel did when the learner died) or the learner's pid is gone, it
SIGKILLs every noted process still alive and any new one naming the session, for at most
`SWEEP_S`, then exits. Nothing else is ever signalled. Linux (/proc) only; elsewhere
`start` returns None and Ray's own clean-up is all there is.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

TICK_S = 0.25
"""How often the instance's processes are noted, and the learner's liveness checked."""
SWEEP_S = 5.0
"""Longest the final sweep keeps killing (a process may fork while it is being killed)."""


def _stat(pid: int) -> tuple[int, int, str] | None:
    """(ppid, start time, state) of a live process, or None (gone, or a zombie: it runs nothing)."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_bytes().decode(errors="replace")
    except OSError:
        return None
    fields = raw[raw.rfind(")") + 2:].split()
    state = fields[0]
    if state in ("Z", "X"):
        return None
    return int(fields[1]), int(fields[19]), state


def _names_session(pid: int, session_dir: str) -> bool:
    try:
        args = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return False
    key = session_dir.rstrip("/").encode()
    return any(a.startswith(b"--") and (a.endswith(key) or key + b"/" in a) for a in args)


def session_processes(session_dir: str, exclude: set[int]) -> dict[int, int]:
    """pid -> start time of the processes that name `session_dir` and their descendants."""
    table: dict[int, tuple[int, int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            st = _stat(int(entry))
            if st is not None:
                table[int(entry)] = (st[0], st[1])
    found = {pid for pid in table if pid not in exclude and _names_session(pid, session_dir)}
    children: dict[int, list[int]] = {}
    for pid, (ppid, _) in table.items():
        children.setdefault(ppid, []).append(pid)
    stack = list(found)
    while stack:
        for child in children.get(stack.pop(), ()):
            if child not in found and child not in exclude:
                found.add(child)
                stack.append(child)
    return {pid: table[pid][1] for pid in found}


def _sweep(noted: dict[int, int], session_dir: str, exclude: set[int]) -> None:
    end = time.monotonic() + SWEEP_S
    while time.monotonic() < end:
        targets = {**noted, **session_processes(session_dir, exclude)}
        alive = {pid for pid, start in targets.items() if (st := _stat(pid)) is not None and st[1] == start}
        if not alive:
            return
        for pid in alive:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        noted = {pid: targets[pid] for pid in alive}
        time.sleep(0.05)


def watch(learner_pid: int, session_dir: str) -> None:
    """The watcher's loop (see the module docstring); returns after the final sweep."""
    exclude = {os.getpid(), learner_pid}
    learner = _stat(learner_pid)
    noted: dict[int, int] = {}
    while True:
        noted.update(session_processes(session_dir, exclude))
        ready, _, _ = select.select([sys.stdin.buffer], [], [], TICK_S)
        if ready and not os.read(sys.stdin.fileno(), 4096):
            break
        now = _stat(learner_pid)
        if learner is None or now is None or now[1] != learner[1]:
            break
    _sweep(noted, session_dir, exclude)


class Reaper:
    """The learner's end: `close()` after `ray.shutdown()` lets the watcher sweep and exit."""

    def __init__(self, proc: subprocess.Popen):
        self.proc = proc

    def close(self, timeout_s: float = SWEEP_S + 2.0) -> None:
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            self.proc.stdin.close()
        try:
            self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def start(session_dir: str) -> Reaper | None:
    """Watch the private Ray instance of `session_dir` for this process; None without /proc."""
    if not Path("/proc/self/stat").exists() or not session_dir:
        return None
    proc = subprocess.Popen(
        [sys.executable, "-I", "-S", str(Path(__file__).resolve()), str(os.getpid()), session_dir],
        stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
        close_fds=True,
    )
    return Reaper(proc)


def main(argv: list[str]) -> int:
    if len(argv) != 2 or not argv[0].isdigit() or not argv[1].startswith("/"):
        print("usage: ray_reaper.py LEARNER_PID SESSION_DIR (an absolute path)", file=sys.stderr)
        return 2
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    watch(int(argv[0]), argv[1])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
