"""`morphmimic robustness` (learner/evaluation/executor/robustness.py, robustness_report.py) on tiny untrained
checkpoints: UniCon Table 2's rows, the files, the unperturbed row at exactly 1, skipped rows
with their reasons, and bad options."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from learner.evaluation.executor import robustness
from tests.learner.evaluation.executor_checkpoints import tiny_executor


def test_rows_are_unicon_table_2() -> None:
    rows = robustness.rows_for(robustness.GROUPS)
    speeds = [r.x for r in rows if r.group == "speed"]
    assert speeds == [0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6]
    assert [int(r.x) for r in rows if r.group == "projectile"] == [1, 5, 10, 20, 30, 40, 50, 60, 70, 80]
    assert [(r.name, r.paper) for r in rows if r.group == "mass"] == [("heavy x1.25", (77.9, 65.7)),
                                                                      ("light x0.75", (98.2, 33.5))]
    assert all(r.paper is not None and not r.perturbation.is_identity for r in rows if r.group != "shape")
    (shape,) = [r for r in rows if r.group == "shape"]  # one row more than Table 2: no paper figure
    assert shape.paper is None and shape.perturbation.shapes == robustness.EXECUTOR_SHAPES and shape.x == 10.0
    assert robustness.row_groups("mass, speed") == ("speed", "mass")


def test_executor_robustness_writes_table_json_and_plot(tmp_path: Path, capsys) -> None:
    run = tiny_executor(tmp_path)
    out = tmp_path / "rob"
    argv = ["--checkpoint", str(run), "--clips", "humanoid3d_run", "--starts", "1", "--rows", "speed,mass,projectile",
            "--out", str(out)]
    assert robustness.main(argv) == 0
    captured = capsys.readouterr()
    printed = captured.out
    assert "[robustness] unperturbed: relative performance 100.0%" in printed
    res = json.loads((out / "robustness.json").read_text())
    measured = 1 + sum("skipped" not in r for r in res["rows"])  # one episode each: the bar counts them all
    assert captured.err.startswith(f"[robustness] {measured}/{measured} episodes in "), captured.err
    assert set(res) == {"meta", "unperturbed", "rows"}
    assert res["unperturbed"]["relative"] == 1.0 and res["unperturbed"]["performance"] > 0
    assert "own termination rule" in res["meta"]["performance"]
    assert len(res["rows"]) == 12 + 10 + 2
    for r in res["rows"]:
        assert "skipped" in r or {"relative", "success_pct", "performance", "paper"} <= set(r)
    ran = [r for r in res["rows"] if "skipped" not in r]
    assert {r["group"] for r in ran} == {"speed", "mass", "projectile"}
    # Every row plays the same (clip, start) episodes; slower playback plans more steps.
    slow = next(r for r in ran if r["row"] == "speed x0.5")
    assert [e["start_s"] for e in slow["episodes"]] == [e["start_s"] for e in res["unperturbed"]["episodes"]]
    assert slow["episodes"][0]["planned_steps"] >= 2 * res["unperturbed"]["episodes"][0]["planned_steps"] - 1
    text = (out / "robustness.md").read_text()
    assert "| unperturbed | 100.0 |" in text and "| speed x0.5 |" in text and "| 47.4 | 10.8 |" in text
    assert "**The projectile**: a ball of 2 kg and 8 cm radius, launched at 10 m/s from 2 m away" in text
    assert "**Performance** = the mean over these episodes of the return" in text
    assert (out / "robustness.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_projectile_flight_steps() -> None:
    rows = {r.perturbation.projectile_every: r for r in robustness.rows_for(("projectile",))}
    assert robustness.projectile_flight_steps(rows[10], 60.0) == 12  # 2 m at 10 m/s
    fast = robustness.rows_for(("projectile",), projectile_speed=40.0)[0]
    assert robustness.projectile_flight_steps(fast, 60.0) == 3


def test_shape_controller_runs_the_mass_rows_and_says_why_it_skips_the_rest(tmp_path: Path) -> None:
    from tests.learner.evaluation.test_evaluate import _tiny_checkpoint

    _tiny_checkpoint(tmp_path, "walker")
    out = tmp_path / "rob"
    assert robustness.main(["--checkpoint", str(tmp_path / "walker"), "--shapes", "2", "--episode-s", "0.3",
                            "--out", str(out)]) == 0
    res = json.loads((out / "robustness.json").read_text())
    assert res["unperturbed"]["relative"] == 1.0
    by_group = {g: [r for r in res["rows"] if r["group"] == g] for g in robustness.GROUPS}
    assert all("skipped" not in r and r["relative"] > 0 for r in by_group["mass"])
    assert all("'speed' task parameter" in r["skipped"] for r in by_group["speed"])
    assert all("no projectile body" in r["skipped"] for r in by_group["projectile"])
    assert "Skipped rows:" in (out / "robustness.md").read_text()


@pytest.mark.parametrize("flag, bad, says", [
    ("--rows", "speed,wind", "--rows: 'speed,wind' must be a comma-separated list of speed, projectile, mass"),
    ("--starts", "0", "--starts = 0 is not allowed: give an integer >= 1"),
    ("--clips", "humanoid3d_nope", "--clips: 'humanoid3d_nope' is no humanoid clip id"),
])
def test_bad_options_are_usage_errors_naming_the_value(flag, bad, says, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        robustness.main(["--checkpoint", "no/such/checkpoint", flag, bad])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert says in err, err


def test_options_of_the_other_kind_of_checkpoint_are_refused(tmp_path: Path, capsys) -> None:
    run = tiny_executor(tmp_path)
    with pytest.raises(SystemExit) as exc:
        robustness.main(["--checkpoint", str(run), "--episode-s", "5"])
    assert exc.value.code == 2 and "--episode-s: not options for task 'executor'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # the executor's --shapes is its shape row's
        robustness.main(["--checkpoint", str(run), "--shapes", "5", "--rows", "mass"])
    assert exc.value.code == 2 and "--shapes, --seed: the executor's shape row" in capsys.readouterr().err
    fish = Path(__file__).resolve().parents[4] / "learner/pretrained/fish"
    with pytest.raises(SystemExit) as exc:
        robustness.main(["--checkpoint", str(fish), "--set", "ankle_armature=0.1"])
    assert exc.value.code == 2 and "--set: not options for task 'fish'" in capsys.readouterr().err


def test_set_runs_the_rows_on_the_changed_body_and_says_so(tmp_path: Path, capsys) -> None:
    run = tiny_executor(tmp_path)
    argv = ["--checkpoint", str(run), "--clips", "humanoid3d_run", "--starts", "1", "--rows", "mass"]
    assert robustness.main([*argv, "--out", str(tmp_path / "a")]) == 0
    assert robustness.main([*argv, "--set", "ankle_armature=0.1", "arm_armature=0.1", "--out", str(tmp_path / "b")]) == 0
    a, b = (json.loads((tmp_path / d / "robustness.json").read_text()) for d in "ab")
    assert b["meta"]["protocol"]["settings"] == ["ankle_armature=0.1", "arm_armature=0.1"]
    assert a["meta"]["protocol"]["settings"] == []
    assert b["unperturbed"]["performance"] != pytest.approx(a["unperturbed"]["performance"])
    assert "`--set ankle_armature=0.1 arm_armature=0.1`" in (tmp_path / "b" / "robustness.md").read_text()
    with pytest.raises(SystemExit) as exc:
        robustness.main([*argv, "--set", "ankle_armature=-1", "--out", str(tmp_path / "c")])
    assert exc.value.code == 2 and "--task.executor.ankle-armature = -1 is not allowed" in capsys.readouterr().err


def test_projectile_rows_throw_the_ball_at_the_character(tmp_path: Path) -> None:
    """Projectile rows run (the balls wait parked, touching nothing), the throws reach the body,
    and a row whose interval times the ball count is shorter than a flight is skipped."""
    from learner import checkpoint
    from learner.evaluation.executor import evaluate as xe

    loaded = checkpoint.load_trained(tiny_executor(tmp_path))
    clips = xe.resolve_clips(["humanoid3d_walk"], loaded.cfg.task)
    assert robustness.projectile_problem(loaded, clips[0]) is None
    rows = [r for r in robustness.rows_for(("projectile",)) if r.perturbation.projectile_every in (1, 20)]
    base, res = robustness.executor_rows(loaded, clips, 1, 1, rows, log=lambda s: None)
    assert all("skipped" not in r and r["relative"] is not None for r in res)
    slow = robustness.rows_for(("projectile",), projectile_speed=0.1)[:1]
    _, (skipped,) = robustness.executor_rows(loaded, clips, 1, 1, slow, log=lambda s: None)
    assert "thrown again before it arrives (1200 steps of flight" in skipped["skipped"]
    env = xe.make_eval_env(loaded, clips, rows[1].perturbation)
    hits = []

    def watch(e, k):
        hits.append(float(np.linalg.norm(e.data.xpos[e.balls[0]] - e.data.xpos[1])))

    policy = checkpoint.make_policy(loaded, env.obs_dim, env.act_dim)
    xe.run_episode(env, policy, "humanoid3d_walk", 0.0, "per_term", seed=0, perturbation=rows[1].perturbation,
                   on_step=watch)
    assert hits[0] > 1.5 and min(hits[:20]) < 0.3  # launched 2 m away, reaches the body within 20 steps
