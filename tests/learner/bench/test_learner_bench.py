"""`morphmimic bench learner --schedules`: whole PPO updates under several epochs x minibatch
schedules on one batch; the schedule text is checked where it enters."""

from __future__ import annotations


import pytest
import torch

from learner.bench import learner_update


def test_schedules_are_parsed_and_bad_ones_named() -> None:
    assert learner_update.parse_schedules("10x128, 5X512") == [(10, 128), (5, 512)]
    with pytest.raises(ValueError, match="'10by128': give EPOCHSxMINIBATCH"):
        learner_update.parse_schedules("10by128")
    with pytest.raises(ValueError, match="'0x128': epochs 1-100"):
        learner_update.parse_schedules("0x128")


def test_fewer_larger_steps_cost_less_per_sample() -> None:
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as the bench and the learner run; two threads contend on a loaded 2-core machine
    try:
        rows = learner_update.measure_schedules("lower_biped-tiny", [(4, 32), (1, 512)], rounds=1)
    finally:
        torch.set_num_threads(threads)
    assert [(r["epochs"], r["minibatch"]) for r in rows] == [(4, 32), (1, 512)]
    assert rows[0]["speedup_vs_first"] == 1.0
    # 4 passes of 32 steps each against one pass of 2 steps: the work differs by far more than load can hide
    assert rows[1]["us_per_sample"] < rows[0]["us_per_sample"]
