"""The `morphmimic` entry and its `bench` dispatcher: help lists every entry, an unknown name is
one line and exit 2."""

from learner import cli
from learner.bench import cli as bench_cli


def test_help_lists_every_command_and_benchmark(capsys) -> None:
    assert cli.main(["--help"]) == 0 and cli.main(["bench", "--help"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in cli.COMMANDS) and all(name in out for name in bench_cli.BENCHMARKS)


def test_an_unknown_name_is_one_line_and_exit_2(capsys) -> None:
    assert cli.main(["trian"]) == 2 and cli.main(["bench", "speed"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "'trian'" in err[0] and "train" in err[0] and "'speed'" in err[1] and "curve" in err[1]
