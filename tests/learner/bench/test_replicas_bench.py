"""`morphmimic bench replicas` on a small preset: both arms run the same updates, and the
replicated one ends where the single process does."""

from __future__ import annotations

from learner.bench import replicas


def test_replicas_bench_compares_the_same_update_in_one_and_two_processes():
    m = replicas.measure("reach-tiny", width=16, updates=1, world=2)
    assert m["single_s"] > 0 and m["replicated_s"] > 0 and m["speedup"] > 0
    assert m["max_param_diff"] < 1e-4


def test_replicas_bench_refuses_a_minibatch_it_cannot_split(capsys):
    import pytest

    with pytest.raises(SystemExit) as exc:
        replicas.main(["--preset", "reach-tiny", "--replicas", "3"])
    assert exc.value.code == 2 and "does not divide" in capsys.readouterr().err
