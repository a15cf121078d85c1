"""`morphmimic bench shape-references` runs both ways on real resets, finds the references and
episodes equal, and rejects bad options clearly."""

from __future__ import annotations

import pytest

from learner.bench import shape_references as bench


def test_the_bench_prints_both_ways_and_finds_them_equal(capsys):
    assert bench.main(["--clips", "humanoid3d_walk", "--library", "0", "--pairs", "2", "--episode-steps", "5"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("reset on a new"))
    assert float(row.split()[-1]) > 0  # whole / on demand
    assert "references bit for bit equal: 2 of 2; episodes (observations, rewards) equal: 2 of 2" in out


@pytest.mark.parametrize("argv, needle", [
    (["--pairs", "0"], "pairs"),
    (["--clips", "", "--library", "0"], "--clips"),
    (["--library", "-1"], "library"),
])
def test_the_bench_rejects_bad_options(argv, needle, capsys):
    with pytest.raises(SystemExit):
        bench.main(argv)
    assert needle in capsys.readouterr().err
