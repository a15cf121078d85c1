"""`morphmimic break-probe` (learner/evaluation/break_probe.py): the root's offsets on hand-made
states, and the command on an untrained executor."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tests.learner.evaluation.executor_checkpoints import tiny_executor


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    return tiny_executor(tmp_path_factory.mktemp("ckpt"))


def _kin(rot: np.ndarray, com=(0.0, 0.0, 0.9)):
    from common.tasks.executor_obs import BodyKin

    z = np.zeros((2, 3))
    pos = np.array([[0.0, 0.0, 0.9], [0.0, 0.0, 0.5]])
    return BodyKin(pos, np.stack([rot, np.eye(3)]), z, z, np.asarray(com, dtype=float))


def _about(axis: int, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i, j = [a for a in range(3) if a != axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def test_a_lean_is_tilt_and_a_turn_is_heading() -> None:
    from learner.evaluation.break_probe import root_offsets

    face_left = _about(2, 90.0)  # the reference faces world +y
    lean = root_offsets(_kin(face_left @ _about(1, 15.0)), _kin(face_left))  # pitched forward in its own frame
    assert lean["tilt_deg"] == pytest.approx(15.0) and lean["rotation_deg"] == pytest.approx(15.0)
    assert lean["heading_deg"] == pytest.approx(0.0, abs=1e-6)
    turn = root_offsets(_kin(_about(2, 110.0)), _kin(face_left))
    assert turn["heading_deg"] == pytest.approx(20.0) and turn["tilt_deg"] == pytest.approx(0.0, abs=1e-6)
    # 10 cm along world +y is 10 cm forward of a reference that faces +y; 5 cm along world +x is to its right
    ahead = root_offsets(_kin(face_left, com=(0.05, 0.1, 0.9)), _kin(face_left))
    assert ahead["com_forward_m"] == pytest.approx(0.1) and ahead["com_left_m"] == pytest.approx(-0.05)


def test_probe_writes_the_tables_and_the_shares_add_up(run_dir: Path, tmp_path: Path) -> None:
    from learner.evaluation import break_probe

    out = tmp_path / "probe"
    assert break_probe.main(["--checkpoint", str(run_dir), "--starts", "1", "--splits", "test", "--out", str(out)]) == 0
    res = json.loads((out / "break_probe.json").read_text())["splits"]["test"]
    assert res["episodes"] == 8  # the test split's 8 clips, one start each
    assert res["success_pct"] <= res["pose_success_pct"]
    # an untrained policy fails the pose terms in most episodes; each failure names at least one term
    fails = res["pose_failures"]
    assert fails == round(8 * (100.0 - res["pose_success_pct"]) / 100.0) >= 4
    assert sum(res["first_term_pct"].values()) >= 100.0 - 1e-9
    assert 0 < res["joint_position_breaks"] <= 8
    assert sum(res["body_share_pct"].values()) == pytest.approx(100.0)
    assert set(res["body_share_pct"]) >= {"left_ankle", "right_wrist"}
    lo, mid, hi = res["quartiles"]["tilt_deg"]
    assert 0.0 <= lo <= mid <= hi <= 180.0
    text = (out / "break_probe.md").read_text()
    assert "| test | 8 |" in text and "largest shares of the squared error" in text


def test_a_bad_setting_and_a_bad_count_are_usage_errors(run_dir: Path, capsys) -> None:
    from learner.evaluation import break_probe

    for argv, words in ((["--set", "ankle_armature=-1"], "--task.executor.ankle-armature = -1 is not allowed"),
                        (["--starts", "0"], "'0' must be an integer >= 1")):
        with pytest.raises(SystemExit) as exc:
            break_probe.main(["--checkpoint", str(run_dir), *argv])
        assert exc.value.code == 2 and words in capsys.readouterr().err
