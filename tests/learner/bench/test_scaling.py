"""`morphmimic bench scaling` end to end on a small local test cluster: every actor x replica
point runs, and the table, JSON and plot are written."""

from __future__ import annotations

import json

import pytest

from learner.bench import scaling

pytestmark = pytest.mark.cluster


def test_scaling_bench_runs_every_point_and_writes_its_files(tmp_path):
    out = tmp_path / "scaling"
    assert scaling.main(["--preset", "reach-tiny", "--actors", "1,2", "--replicas", "1,2", "--envs-per-actor", "4",
                         "--iterations", "3", "--warmup", "1", "--out", str(out)]) == 0
    data = json.loads((out / "scaling.json").read_text())
    assert [(r["actors"], r["replicas"]) for r in data["rows"]] == [(1, 1), (1, 2), (2, 1), (2, 2)]
    for row in data["rows"]:
        assert row["fresh_steps_per_s"] > 0 and 0 < row["learner_share"] < 1 and row["timed_iterations"] == 1
    assert (out / "scaling.png").stat().st_size > 10_000
    assert "| 2 | 2 |" in (out / "scaling.md").read_text()


def test_scaling_bench_refuses_counts_it_cannot_run(capsys):
    with pytest.raises(SystemExit) as exc:
        scaling.main(["--actors", "0,2"])
    assert exc.value.code == 2 and "--actors = (0, 2) is not allowed: give each an integer >= 1" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        scaling.main(["--preset", "reach-tiny", "--replicas", "3"])
    assert exc.value.code == 2 and "does not divide" in capsys.readouterr().err
