"""Stall detection by heartbeat: counted once, excluded, re-admitted when the actor sends again."""

from __future__ import annotations

from learner.health import HealthMonitor


def test_stall_is_counted_once_and_readmission_too():
    seen = {0: 100.0, 1: 100.0}
    lines: list[str] = []
    h = HealthMonitor(seen, stall_timeout_s=5.0, say=lines.append)
    h.check(now=103.0)
    assert h.alive() == 2 and h.stalls == 0
    seen[1] = 104.0
    h.check(now=106.0)
    h.check(now=107.0)
    assert h.stalled == {0} and h.stalls == 1 and h.alive() == 1
    seen[0] = 107.5
    h.check(now=108.0)
    assert h.stalled == set() and h.readmissions == 1 and h.alive() == 2
    assert any("actor 0" in line and "stalled" in line for line in lines)
    assert any("re-admitted" in line for line in lines)
