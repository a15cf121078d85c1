"""`morphmimic bench episodes` runs on a real environment and rejects bad options clearly."""

from __future__ import annotations

import pytest

from learner.bench import episodes as bench


def test_episode_bench_prints_a_row_with_a_ratio(capsys):
    assert bench.main(["--tasks", "fish", "--resets", "2", "--steps", "10"]) == 0
    row = capsys.readouterr().out.strip().splitlines()[-1].split()
    assert row[0] == "fish"
    assert float(row[5]) > 0  # reset / step


@pytest.mark.parametrize("argv, needle", [
    (["--tasks", "dragon"], "unknown task(s) ['dragon']"),
    (["--lengths", "40"], "give two positive episode lengths"),
    (["--lengths", "40,many"], "give two positive episode lengths"),
])
def test_episode_bench_rejects_bad_options(argv, needle, capsys):
    with pytest.raises(SystemExit):
        bench.main(argv)
    assert needle in capsys.readouterr().err
