"""A swimmer's evaluation figures (`learner.evaluation.shape.swim_metrics`): on hand-made states of a
real fish, and through `morphmimic evaluate` on a tiny untrained fish checkpoint."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from common.tasks.registry import make_env, task_space
from learner import checkpoint
from learner.evaluation.shape.swim_metrics import SwimTracker, summarize_swim
from learner.presets import PRESETS


def _fish_env():
    cfg = PRESETS["fish"][1].task
    env = make_env(cfg, seed=0)
    env.reset(0, task_space(cfg).default_array)
    return env


def _set_com_velocity(env, v: np.ndarray) -> None:
    """Fill the env's 2 s COM window so that its averaged velocity is `v` `[2]`."""
    start = np.array([0.0, 0.0, 1.0])
    env.com_hist.clear()
    for i in range(env.com_hist.maxlen):
        env.com_hist.append(start + np.array([v[0], v[1], 0.0]) * i * env.dt)


def test_speed_heading_and_upright_on_hand_made_states() -> None:
    env = _fish_env()
    vt = env.target_velocity()
    assert np.linalg.norm(vt) > 0.05  # the fish's clip swims forward
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    _set_com_velocity(env, 1.5 * np.array([[c, -s], [s, c]]) @ vt)
    env.data.qpos[3:7] = env.ref_q[0][3:7]  # the reference's own attitude: upright
    tracker = SwimTracker()
    tracker(env, k=100)
    # rolled 90 degrees about its own forward axis: belly sideways, not upright
    q = env.ref_q[0][3:7]
    roll = np.array([math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])
    w1, x1, y1, z1 = q
    w2, x2, y2, z2 = roll
    env.data.qpos[3:7] = [w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                          w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2]
    tracker(env, k=101)
    r = tracker.result()
    assert r["swim_speed_error_pct"] == pytest.approx(50.0, abs=1e-6)
    assert r["swim_speed_error_length_pct"] == r["swim_speed_error_pct"]  # the fish keeps the length rule
    assert r["swim_heading_error_deg"] == pytest.approx(30.0, abs=1e-6)
    assert r["swim_upright_pct"] == pytest.approx(50.0)
    assert r["swim_speed_m_s"] == pytest.approx(1.5 * np.linalg.norm(vt))


def test_the_warm_up_is_left_out_of_speed_and_heading() -> None:
    env = _fish_env()
    _set_com_velocity(env, np.zeros(2))
    tracker = SwimTracker()
    tracker(env, k=1)  # inside the first 2 s
    r = tracker.result()
    assert r["swim_speed_error_pct"] is None and r["swim_heading_error_deg"] is None
    assert r["swim_upright_pct"] == 100.0
    assert summarize_swim([r]) == {"swim_upright_pct": 100.0}
    assert summarize_swim([{"return": 1.0}]) == {}  # a walker's results carry none


def test_evaluate_reports_swimming_figures_for_a_fish(tmp_path: Path, capsys) -> None:
    from learner.evaluation import evaluate
    from learner.learner import Learner

    cfg = dataclasses.replace(PRESETS["fish"][1], name="tiny-fish")
    checkpoint.save(tmp_path / "tiny-fish" / "ckpt", 0, Learner(cfg).state_dict(), keep=1)
    out = tmp_path / "eval"
    assert evaluate.main(["--checkpoint", str(tmp_path / "tiny-fish"), "--shapes", "2", "--episode-s", "3",
                          "--no-render", "--out", str(out)]) == 0
    assert "swimming: speed error" in capsys.readouterr().out
    res = json.loads((out / "results.json").read_text())
    for r in res["shapes"]:
        assert 0.0 <= r["swim_upright_pct"] <= 100.0
        assert (r["swim_speed_error_pct"] is None) == (r["seconds"] < 2.0)
    summary = (out / "summary.md").read_text()
    assert "swim heading error" in summary and "time upright" in summary
    assert "length rule" in summary and json.loads((out / "results.json").read_text())["meta"]["swimmer_speed"] == "length"


def test_evaluate_refuses_a_floor_retargeting_for_a_swimmer(tmp_path: Path) -> None:
    from learner.evaluation import evaluate
    from learner.learner import Learner

    cfg = dataclasses.replace(PRESETS["manta"][1], name="tiny-manta")
    checkpoint.save(tmp_path / "tiny-manta" / "ckpt", 0, Learner(cfg).state_dict(), keep=1)
    with pytest.raises(SystemExit, match="is a swimmer"):
        evaluate.main(["--checkpoint", str(tmp_path / "tiny-manta"), "--shapes", "1", "--clearance", "0.01"])
