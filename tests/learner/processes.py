"""Test helper: the processes a learner started, each known by pid and start time, so a zombie
awaiting its reaper or a new process under a reused pid is never taken for one of them."""

from __future__ import annotations

import os
from pathlib import Path

from learner import ray_reaper


def descendants(pid: int) -> dict[int, int]:
    """pid -> start time of every live descendant of `pid` (from /proc)."""
    table = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (st := ray_reaper._stat(int(entry))) is not None:
            table[int(entry)] = st
    out, stack = {}, [pid]
    while stack:
        parent = stack.pop()
        for child, (ppid, start, _) in table.items():
            if ppid == parent and child not in out:
                out[child] = start
                stack.append(child)
    return out


def alive(pids: dict[int, int]) -> dict[int, str]:
    """pid -> program name of those of `pids` (pid -> start time) still running as themselves."""
    out = {}
    for pid, start in pids.items():
        st = ray_reaper._stat(pid)
        if st is not None and st[1] == start:
            try:
                argv0 = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0].decode(errors="replace")
            except OSError:  # it ended between the two reads
                continue
            out[pid] = Path(argv0).name  # the program's name: a clone's path may be any length
    return out
