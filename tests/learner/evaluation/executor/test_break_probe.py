"""`morphmimic break-probe` (learner/evaluation/executor/break_probe.py): the root's offsets on hand-made
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
    from common.tasks.executor.observations import BodyKin

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
    from learner.evaluation.executor.break_probe import root_offsets

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
    from learner.evaluation.executor import break_probe

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
    from learner.evaluation.executor import break_probe

    for argv, words in ((["--set", "ankle_armature=-1"], "--task.executor.ankle-armature = -1 is not allowed"),
                        (["--starts", "0"], "--starts = 0 is not allowed: give an integer >= 1")):
        with pytest.raises(SystemExit) as exc:
            break_probe.main(["--checkpoint", str(run_dir), *argv])
        assert exc.value.code == 2 and words in capsys.readouterr().err


def test_the_probes_refuse_what_they_cannot_measure_before_any_episode(run_dir: Path, tmp_path: Path, capsys) -> None:
    from learner.evaluation.executor import break_probe
    from learner.evaluation.executor import velocity_probe

    a_file = tmp_path / "taken"
    a_file.write_text("not a folder")
    cases = [
        (break_probe, ["--set", "terminate_on=joint_position"], "no figure of the probe depends on terminate_on"),
        (break_probe, ["--splits", "unused"], "--splits unused: no clip of xtiny is in that split"),
        (break_probe, ["--out", str(a_file / "probe")], f"--out {a_file / 'probe'}: cannot make that folder"),
        (velocity_probe, ["--set", "joint_velocity=step_mean"], "the probe reads the simulator's instant joint velocities"),
    ]
    for module, argv, says in cases:
        with pytest.raises(SystemExit) as exc:
            module.main(["--checkpoint", str(run_dir), *argv])
        assert exc.value.code == 2, argv
        assert says in capsys.readouterr().err, argv


def test_a_step_that_diverged_adds_nothing_to_either_probe(run_dir: Path) -> None:
    """A diverged step leaves the previous step's terms (or none, on the first step) in
    `env.last_terms`: the hooks skip it instead of reading stale or missing terms."""
    from learner import checkpoint
    from learner.evaluation.executor import evaluate as xe
    from learner.evaluation.executor.break_probe import BreakHook
    from learner.evaluation.executor.velocity_probe import EpisodeProbe, joint_of_dof, left_out_mask

    loaded = checkpoint.load_trained(run_dir)
    env = xe.make_eval_env(loaded, xe.resolve_clips(["humanoid3d_walk"], loaded.cfg.task))
    env.reset(0, env.space.default_array, clip_id="humanoid3d_walk", start_s=0.0)
    velocity = EpisodeProbe(env, left_out_mask(joint_of_dof(env.ref_model), ["ankle"]))
    pose = BreakHook(env)
    for hook in (velocity, pose):
        hook(env, 1)  # last_terms is still reset's {}
    assert velocity.dof_steps == {True: 0, False: 0} and pose.first_pose is None
    env.step(np.zeros(env.nu))
    velocity(env, 1)
    velocity(env, 2)  # the same terms again: skipped
    assert velocity.dof_steps[True] + velocity.dof_steps[False] == 6


def test_a_saved_config_naming_clips_the_humanoid_lacks_is_refused_at_load(run_dir: Path, tmp_path: Path) -> None:
    from learner import checkpoint
    from learner import checkpoint

    state = checkpoint.load(checkpoint.resolve(run_dir))
    raw = json.loads(state["config"])
    raw["task"]["executor"]["clips"] = ["nope_clip"]
    state["config"] = json.dumps(raw)
    checkpoint.save(tmp_path / "ckpt", 1, state, keep=1)
    with pytest.raises(SystemExit, match=r"its saved configuration is refused: clips \['nope_clip'\] do not play"):
        checkpoint.load_trained(tmp_path)
