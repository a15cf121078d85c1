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


def test_train_help_is_short_and_help_all_is_the_whole_tree(capsys) -> None:
    import pytest

    from learner import main as train_main

    for argv in (["--help"], ["--preset", "executor", "--help"], ["--help-all"]):
        with pytest.raises(SystemExit) as exit_info:
            train_main.parse(argv)
        assert exit_info.value.code == 0
    short, executor, full = capsys.readouterr().out.split("usage: ")[1:4]
    assert len(short.splitlines()) < 60 < 400 < len(full.splitlines())
    for name in train_main.SHORT_HELP:  # generated from RunConfig: every listed field, with its docstring
        assert f"--{name.replace('_', '-')}" in short
    assert "--preset NAME" in short and "--help-all shows every option" in short and "Step budget" in short
    assert "(default: 400000)" in short and "(default: 50000000)" in executor  # the chosen preset's defaults
    assert "--ppo.lr" in full and "--ppo.lr" not in short


def test_a_missing_checkpoint_is_one_line_and_exit_2_for_every_command_that_takes_one(tmp_path, capsys) -> None:
    missing = str(tmp_path / "no-such-run")
    for argv in (["evaluate", "--checkpoint", missing], ["play", "--checkpoint", missing, "--seconds", "1"],
                 ["robustness", "--checkpoint", missing]):
        assert cli.main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"morphmimic {argv[0]}: ") and "no-such-run" in err[0], err
