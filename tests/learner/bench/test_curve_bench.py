"""`morphmimic bench curve` runs both modes over real sockets and prints their ratio."""

from learner.bench import curve as bench_curve


def test_the_curve_bench_compares_plain_and_curve_sockets(capsys) -> None:
    assert bench_curve.main(["--obs-dim", "8", "--rounds", "1", "--messages", "5", "--round-trips", "20"]) == 0
    out = capsys.readouterr().out
    assert "unroll stream" in out and "round trips" in out and out.count("ratio") >= 2
