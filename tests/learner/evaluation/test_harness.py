"""The evaluation's process pool ends whatever signal handlers its parent holds."""

from __future__ import annotations

import signal
import sys
import time

from learner.evaluation.harness import run_jobs


def _no_setup() -> None:
    pass


def _echo(job: int) -> dict:
    time.sleep(0.01)
    return {"index": job, "handler": signal.getsignal(signal.SIGTERM) == signal.SIG_DFL}


def test_a_pool_ends_when_the_parent_holds_a_python_sigterm_handler():
    """`ray.init` leaves a SIGTERM handler raising SystemExit in the driver; forked workers
    inherited it and survived the pool's SIGTERM at its end, so the pool's join hung for good (a
    CI run timed out so). The workers now reset it: the pool ends, every job ran with the
    default disposition, results come back in order."""
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(signum))
    try:
        for _ in range(3):
            results = run_jobs(_no_setup, (), _echo, [3, 1, 2, 0], workers=2)
            assert [r["index"] for r in results] == [0, 1, 2, 3]
            assert all(r["handler"] for r in results)
    finally:
        signal.signal(signal.SIGTERM, previous)
