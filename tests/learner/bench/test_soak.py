"""`morphmimic bench soak`: the short soak CI runs (the real command on the local two-worker
test cluster, all on this machine: every in-process fault kind and a NaN checkpoint, which also
SIGKILLs the learner and resumes it), and the report's arithmetic on status files."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from learner.bench.soak_faults import IN_PROCESS_KINDS
from learner.bench.soak_report import SoakRecord, report

ROOT = Path(__file__).resolve().parents[3]
pytestmark = pytest.mark.cluster


def test_a_short_soak_injects_every_fault_and_reports_what_it_found() -> None:
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    args = [sys.executable, "-m", "learner.cli", "bench", "soak", "--minutes", "0.5", "--preset", "reach-tiny",
            "--fault-every", "1", "--stall-limit", "60", "--no-clean", "--faults", *IN_PROCESS_KINDS, "nan_checkpoint"]
    # NOTE: --stall-limit 60: with two actors, an actor kill and a 2-12 s stall in one iteration
    # leave none sending while Ray restarts the killed one (20-47 s in CI); a 20 s limit had the
    # soak kill that waiting learner, and the kinds due after it never came.
    proc = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True, timeout=420)
    out = proc.stdout
    print(out)  # the soak's report, in the test log
    assert proc.returncode in (0, 1), out[-3000:] + proc.stderr[-3000:]  # 1: a goal missed, which today's code may
    lines = {line.split(":", 1)[0].strip(): line for line in out.splitlines() if ":" in line}
    assert "faults injected" in lines, out[-3000:] + proc.stderr[-3000:]
    injected = lines["faults injected"]
    for kind in (*IN_PROCESS_KINDS, "nan_checkpoint"):
        assert f"{kind} " in injected, f"{kind} was not injected:\n{out[-3000:]}"
    for key in ("load held", "faults survived", "losses counted", "losses uncounted", "bookkeeping", "counters by name",
                "return", "soak verdict"):
        assert key in lines, f"no {key!r} line:\n{out[-3000:]}"
    assert "not injected (the soak ended first)" not in out


def _status(**kw) -> dict:
    base = {"iteration": 40, "env_steps": 40960, "episodes": 500, "return": 30.0, "final": True, "faults": [],
            "counters": {"unrolls_received": 171, "unrolls_trained": 160, "stale_unrolls": 4, "unused_at_stop": 6,
                         "unused_at_resume": 1, "seq_gap_unrolls": 1, "late_unrolls": 1},
            "learner_counters": {"divergences": 3}, "metrics": {}, "ledger": {"0": 86, "1": 86},
            "last_seq": {"0": 85, "1": 85}}
    base.update(kw)
    return base


def test_the_report_balances_the_ledger_and_compares_with_the_clean_run() -> None:
    lines: list[str] = []
    rec = SoakRecord(minutes=1.0, wall_s=60.0, longest_stall_s=4.0,
                     segments=[_status(faults=[{"kind": "kill_actor", "iteration": 3, "at": 0.0, "outcome": "survived"}])],
                     clean={**_status(**{"return": 31.0}), "wall_s": 50.0})
    assert report(rec, out=lines.append)
    text = "\n".join(lines)
    assert "losses counted:   12 " in text and "losses uncounted: 0 " in text, text
    assert "unused at stop 6, unused by a killed session 1," in text and "late arrivals 1, not gaps" in text, text
    assert "faults survived:  1/1" in text and "3.2% apart" in text


def test_forged_counters_show_as_negative_uncounted_and_impossible_divergences() -> None:
    lines: list[str] = []
    forged = _status(counters={"unrolls_received": 171, "unrolls_trained": 161, "stale_unrolls": 4, "unused_at_stop": 6,
                               "seq_gap_unrolls": 2**53}, learner_counters={"divergences": 2**53})
    assert not report(SoakRecord(minutes=1.0, wall_s=60.0, segments=[forged]), out=lines.append)
    text = "\n".join(lines)
    assert "forged counters accepted" in text and "(more than episodes: forged)" in text, text


def test_an_unknown_fault_kind_is_one_line_exit_2() -> None:
    proc = subprocess.run([sys.executable, "-m", "learner.cli", "bench", "soak", "--faults", "meteor"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    err = proc.stderr.strip()
    assert "'meteor' is not a fault kind" in err and "\n" not in err, err
