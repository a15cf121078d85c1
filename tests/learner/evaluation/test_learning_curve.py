"""The learning curve's bookkeeping: wall time of old checkpoints and reuse of earlier rows."""

from __future__ import annotations

import json
import os
import re

import pytest

from learner import checkpoint
from learner.evaluation.learning_curve import _earlier_rows, _wall_from_file_times, every_nth


def _fake_checkpoints(tmp_path, stamps: dict[int, float]):
    out = []
    for iteration, t in stamps.items():
        d = tmp_path / f"{iteration:08d}"
        d.mkdir()
        (d / checkpoint.FILE).write_bytes(b"")
        os.utime(d / checkpoint.FILE, (t, t))
        out.append(d)
    return out


def test_wall_time_from_file_times_leaves_out_the_pause_between_sessions(tmp_path):
    """10 s per iteration, a checkpoint every 10; a 2-hour pause between iterations 30 and 40;
    config.json rewritten by the resume (later than the first checkpoint)."""
    t0 = 1_000_000.0
    ckpts = _fake_checkpoints(tmp_path, {10: t0 + 100, 20: t0 + 200, 30: t0 + 300, 40: t0 + 7500, 50: t0 + 7600})
    wall = _wall_from_file_times(ckpts, start=t0)
    assert [wall[c] for c in ckpts] == pytest.approx([100, 200, 300, 400, 500])
    resumed = _wall_from_file_times(ckpts, start=t0 + 7300)
    assert [resumed[c] for c in ckpts] == pytest.approx([100, 200, 300, 400, 500])


def test_wall_time_never_runs_backwards_when_a_checkpoint_was_copied_later(tmp_path):
    """A lineage directory mixing copies (new file times) with the original checkpoints: the
    copied one counts at the median rate instead of making the clock go back."""
    t0 = 1_000_000.0
    ckpts = _fake_checkpoints(tmp_path, {10: t0 + 100, 20: t0 + 200, 30: t0 + 90_000, 40: t0 + 400, 50: t0 + 500})
    wall = [_wall_from_file_times(ckpts, start=t0)[c] for c in ckpts]
    assert all(b > a for a, b in zip(wall, wall[1:])), wall
    assert wall[:2] == pytest.approx([100, 200])


def test_earlier_rows_are_reused_only_for_the_same_protocol_and_another_is_refused(tmp_path):
    path = tmp_path / "curve.json"
    rows = [{"iteration": 10, "env_steps": 81920, "fall_down_pct": 90.0}]
    path.write_text(json.dumps({"shapes": 100, "episode_s": 10.0, "seed": 2019, "extreme": "base", "rows": rows}))
    same = dict(shapes=100, episode_s=10.0, seed=2019, box_scale=1.0)
    assert _earlier_rows(path, same) == ({10: rows[0]}, {})  # a curve.json from before --box-scale: the whole box
    before = path.read_text()
    with pytest.raises(SystemExit, match=r"shapes 100.*asks for shapes 300.*another --out"):
        _earlier_rows(path, dict(shapes=300, episode_s=10.0, seed=2019, box_scale=1.0))
    with pytest.raises(SystemExit, match=r"box_scale 1\.0.*asks for box_scale 0\.5"):
        _earlier_rows(path, dict(shapes=100, episode_s=10.0, seed=2019, box_scale=0.5))
    assert path.read_text() == before
    path.write_text("{not json")
    with pytest.raises(SystemExit, match="unreadable curve"):
        _earlier_rows(path, same)


def test_rows_from_before_the_extreme_ranking_changed_are_stale(tmp_path):
    """A curve.json without the "extreme" version ranked the extreme 10% from the box centre:
    its rows come back as stale (measured again where the checkpoint still exists)."""
    path = tmp_path / "curve.json"
    rows = [{"iteration": 10, "env_steps": 81920, "fall_down_pct": 90.0, "fall_down_pct_extreme10": 95.0}]
    path.write_text(json.dumps({"shapes": 100, "episode_s": 10.0, "seed": 2019, "box_scale": 1.0, "rows": rows}))
    assert _earlier_rows(path, dict(shapes=100, episode_s=10.0, seed=2019, box_scale=1.0)) == ({}, {10: rows[0]})


def test_rows_of_checkpoints_gone_since_are_kept_in_order(tmp_path):
    """A run keeps only its newest checkpoints: the curve keeps the rows measured before the
    older ones were deleted, and adds the new checkpoint's row in iteration order."""
    import dataclasses

    from learner.evaluation import learning_curve
    from learner.learner import Learner
    from learner.presets import PRESETS

    cfg = dataclasses.replace(PRESETS["lower_biped-tiny"][1], name="tiny")
    state = Learner(cfg).state_dict()
    state["iteration"], state["env_steps"] = 7, 7168
    checkpoint.save(tmp_path / "ckpt", 7, state, keep=1)
    out = tmp_path / "curve"
    out.mkdir()
    gone = {"iteration": 3, "env_steps": 3072, "wall_s": 30.0, "shapes": 2, "task_achievement": 1.0,
            "fall_down_pct": 50.0, "fall_down_pct_extreme10": 100.0, "mean_return": 2.0, "mean_seconds": 0.1}
    (out / "curve.json").write_text(json.dumps({"shapes": 2, "episode_s": 0.2, "seed": 2019, "box_scale": 1.0,
                                                "extreme": "base", "rows": [gone]}))
    argv = ["--ckpt-dir", str(tmp_path / "ckpt"), "--shapes", "2", "--episode-s", "0.2", "--out", str(out)]
    assert learning_curve.main(argv) == 0
    rows = json.loads((out / "curve.json").read_text())["rows"]
    assert [r["iteration"] for r in rows] == [3, 7]
    assert rows[0] == gone and rows[1]["env_steps"] == 7168
    # The same history written before the extreme-10% ranking changed: the row of the deleted
    # checkpoint keeps its fall-down % but loses its extreme-10% figure; the live one is measured.
    (out / "curve.json").write_text(json.dumps({"shapes": 2, "episode_s": 0.2, "seed": 2019, "box_scale": 1.0,
                                                "rows": [gone, {**rows[1], "fall_down_pct_extreme10": 12.5}]}))
    assert learning_curve.main(argv) == 0
    data = json.loads((out / "curve.json").read_text())
    assert data["extreme"] == "base"
    assert data["rows"][0] == {**gone, "fall_down_pct_extreme10": None}
    assert data["rows"][1]["fall_down_pct_extreme10"] in (0.0, 100.0)


def test_every_nth_does_not_shift_when_the_oldest_checkpoints_are_deleted(tmp_path):
    ckpts = _fake_checkpoints(tmp_path, {i: 0.0 for i in range(10, 310, 10)})
    chosen = [int(c.name) for c in every_nth(ckpts, 6)]
    assert chosen == [10, 60, 120, 180, 240, 300]
    later = [int(c.name) for c in every_nth(ckpts[3:], 6)]  # 10, 20, 30 deleted by the run
    assert later == [40, 60, 120, 180, 240, 300]


def test_every_first_keeps_a_checkpoint_saved_off_the_grid(tmp_path):
    """A run stopped at iteration 173 saves it between 170 and 180: `--every 1` keeps it."""
    ckpts = sorted(_fake_checkpoints(tmp_path, {150: 0.0, 160: 0.0, 170: 0.0, 173: 0.0, 180: 0.0, 190: 0.0}))
    assert [int(c.name) for c in every_nth(ckpts, 1)] == [150, 160, 170, 173, 180, 190]


def test_curve_end_to_end_writes_rows_and_reuses_them(tmp_path, capsys):
    """Two tiny untrained checkpoints: the curve evaluates both, writes curve.json and curve.png;
    a second call with the same protocol evaluates nothing and keeps the rows."""
    import dataclasses
    import json

    from learner.evaluation import learning_curve
    from learner.learner import Learner
    from learner.presets import PRESETS

    cfg = PRESETS["lower_biped-tiny"][1]
    state = Learner(dataclasses.replace(cfg, name="tiny")).state_dict()
    for it in (0, 10):
        checkpoint.save(tmp_path / "ckpt", it, {**state, "iteration": it, "env_steps": it * 1024}, keep=5)
    argv = ["--ckpt-dir", str(tmp_path / "ckpt"), "--shapes", "2", "--episode-s", "0.3", "--out", str(tmp_path / "curve")]
    assert learning_curve.main(argv) == 0
    first = capsys.readouterr().out
    assert first.count("[curve] it") == 2
    assert "reached 20% fall-down" in first or "never reached 20%" in first
    data = json.loads((tmp_path / "curve" / "curve.json").read_text())
    assert [r["iteration"] for r in data["rows"]] == [0, 10] and all(0 <= r["fall_down_pct"] <= 100 for r in data["rows"])
    assert (tmp_path / "curve" / "curve.png").read_bytes()[:4] == b"\x89PNG"
    assert learning_curve.main(argv) == 0
    assert capsys.readouterr().out.count("[curve] it") == 0
    assert json.loads((tmp_path / "curve" / "curve.json").read_text())["rows"] == data["rows"]


def test_an_executor_runs_curve_is_its_success_per_split_and_grows_by_its_new_checkpoints(tmp_path, capsys):
    """An executor run's curve: UniCon's success per split per checkpoint, the same figures as
    `morphmimic evaluate` on that checkpoint; a later call measures only the new checkpoint,
    and a shape controller's curve.json in --out is refused, not overwritten."""
    from learner.evaluation import learning_curve
    from learner.evaluation.executor import evaluate as xe
    from learner.learner import Learner
    from tests.learner.evaluation.executor_checkpoints import tiny_executor

    run = tiny_executor(tmp_path, clips=("humanoid3d_walk",))
    loaded = checkpoint.load_trained(run)
    state = Learner(loaded.cfg).state_dict()
    state["iteration"], state["env_steps"] = 5, 5120
    checkpoint.save(run / "ckpt", 5, state, keep=5)
    argv = ["--ckpt-dir", str(run / "ckpt"), "--starts", "1", "--workers", "2", "--out", str(tmp_path / "curve")]
    assert learning_curve.main(argv) == 0
    data = json.loads((tmp_path / "curve" / "curve.json").read_text())
    assert data["task"] == "executor" and data["starts"] == 1 and "humanoid3d_walk" in data["clips"]
    assert [r["iteration"] for r in data["rows"]] == [0, 5] and data["rows"][1]["env_steps"] == 5120
    assert set(data["rows"][0]["splits"]) == {"train", "test", "unused"}
    clips = xe.default_clips(loaded.cfg.task)
    direct = xe.summarize(xe.evaluate(loaded, clips, 1), clips)
    for split in ("train", "test"):
        for field in ("success_pct", "pose_success_pct", "phc_success_pct"):
            assert data["rows"][0]["splits"][split][field] == direct["splits"][split][field]
    assert (tmp_path / "curve" / "curve.png").stat().st_size > 0
    printed = capsys.readouterr().out
    assert "never reached 90% train success" in printed and "train " in printed

    checkpoint.save(run / "ckpt", 9, {**state, "iteration": 9, "env_steps": 9216}, keep=5)
    assert learning_curve.main(argv) == 0
    out = capsys.readouterr().out
    assert out.count("[curve] it") == 1 and "it     9" in out
    assert [r["iteration"] for r in json.loads((tmp_path / "curve" / "curve.json").read_text())["rows"]] == [0, 5, 9]

    shape_curve = tmp_path / "shape-curve"
    shape_curve.mkdir()
    (shape_curve / "curve.json").write_text(json.dumps({"shapes": 100, "episode_s": 10.0, "seed": 2019, "rows": []}))
    with pytest.raises(SystemExit, match="task None.*asks for task 'executor'"):
        learning_curve.main(argv[:-1] + [str(shape_curve)])


@pytest.mark.parametrize("flag, value", [("--shapes", "10"), ("--episode-s", "5"), ("--seed", "3"), ("--box-scale", "0.5")])
def test_shape_options_on_an_executor_run_are_a_usage_error(tmp_path, flag, value, capsys):
    from learner.evaluation import learning_curve
    from tests.learner.evaluation.executor_checkpoints import tiny_executor

    run = tiny_executor(tmp_path)
    with pytest.raises(SystemExit) as exc:
        learning_curve.main(["--ckpt-dir", str(run / "ckpt"), flag, value, "--out", str(tmp_path / "c")])
    assert exc.value.code == 2
    assert f"{flag}: options of a shape controller's curve" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()


def test_starts_on_a_shape_run_is_a_usage_error(tmp_path, capsys):
    import dataclasses

    from learner.evaluation import learning_curve
    from learner.learner import Learner
    from learner.presets import PRESETS

    cfg = dataclasses.replace(PRESETS["lower_biped-tiny"][1], name="tiny")
    checkpoint.save(tmp_path / "ckpt", 1, Learner(cfg).state_dict(), keep=1)
    with pytest.raises(SystemExit) as exc:
        learning_curve.main(["--ckpt-dir", str(tmp_path / "ckpt"), "--starts", "3"])
    assert exc.value.code == 2
    assert "--starts: an option of an executor's curve" in capsys.readouterr().err


@pytest.mark.parametrize("executor, row, says", [
    (False, {"iteration": 10, "env_steps": 100, "fall_down_pct": "high"}, "fall_down_pct = 'high'"),
    (False, {"iteration": "10", "env_steps": 100, "fall_down_pct": 5.0}, "iteration = '10'"),
    (False, {"iteration": 10, "env_steps": 10**400, "fall_down_pct": 5.0}, "env_steps = "),
    (False, {"iteration": 10, "env_steps": 100, "fall_down_pct": 5.0, "wall_s": [1]}, "wall_s = [1]"),
    (False, [10, 100], "unreadable curve"),
    (True, {"iteration": 10, "env_steps": 100, "splits": 5}, "splits = 5"),
    (True, {"iteration": 10, "env_steps": 100, "splits": {"train": []}}, "splits['train'] = []"),
    (True, {"iteration": 10, "env_steps": 100, "splits": {"train": {"success_pct": True}}}, "splits['train']['success_pct'] = True"),
])
def test_an_earlier_row_of_the_wrong_type_is_refused_naming_it(tmp_path, executor, row, says):
    """A curve.json read back is input: a row that lacks or mistypes a figure the curve reads is
    refused in one line naming it (before any checkpoint is evaluated), and the file is kept."""
    path = tmp_path / "curve.json"
    proto = {"task": "executor", "starts": 1, "clips": ["a"]} if executor else dict(shapes=1, episode_s=1.0, seed=1, box_scale=1.0)
    path.write_text(json.dumps({**proto, "extreme": "base", "rows": [row]}))
    before = path.read_text()
    with pytest.raises(SystemExit, match=re.escape(says)):
        _earlier_rows(path, proto, family="executor" if executor else "shape")
    assert path.read_text() == before
