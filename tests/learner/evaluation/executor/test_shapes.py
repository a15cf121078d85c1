"""The executor over body shapes in evaluation (issue 55 item 3): `evaluate --shapes` on a tiny
executor really trained with `--task.body.vary-shape` and, zero-shot, on a base-body one; the
mid-episode body change (`ExecutorEnv.set_shape`) and `evaluate --morph`; the robustness suite's
shape row; `--clips-per-shape` (a balanced, seeded rotation of the clips over the shapes) and the
worst decile of the success map. Real MuJoCo throughout."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from common.characters.character import extent
from common.params import ParamSpace
from common.tasks.executor.env import humanoid_clips
from learner import checkpoint
from learner.evaluation.executor import evaluate as xe
from learner.evaluation.executor import report, robustness
from tests.learner.evaluation.executor_checkpoints import tiny_executor, tiny_shape_executor

CLIP = "humanoid3d_walk"


@pytest.fixture(scope="module")
def shaped(tmp_path_factory):
    return tiny_shape_executor(tmp_path_factory.mktemp("shape"))


@pytest.fixture(scope="module")
def fixed(tmp_path_factory):
    return tiny_executor(tmp_path_factory.mktemp("fixed"), "xfixed", actuation="pd")


def _walk_env(run, steps: int = 20, shape=None):
    loaded = checkpoint.load_trained(run)
    env = xe.make_eval_env(loaded, [], shapes=True)
    env.reset(0, env.space.default_array if shape is None else np.array(shape), clip_id=CLIP, start_s=0.0)
    for _ in range(steps):
        env.step(np.zeros(env.act_dim))
    return env


def test_the_checkpoint_is_really_trained_over_shapes(shaped) -> None:
    loaded = checkpoint.load_trained(shaped)
    assert loaded.cfg.task.body.vary_shape and loaded.cfg.task.body.parameterization == "height_thickness"
    assert loaded.state["iteration"] == 2 and loaded.state["env_steps"] >= 512


def test_shapes_are_seeded_and_inside_the_parameterizations_box(shaped, fixed) -> None:
    a, b = (checkpoint.load_trained(r).cfg.task for r in (shaped, fixed))
    s = xe.eval_shapes(a, 16, 7)
    np.testing.assert_array_equal(s, xe.eval_shapes(a, 16, 7))
    np.testing.assert_array_equal(s, xe.eval_shapes(b, 16, 7))  # a base-body checkpoint meets the same bodies
    assert not np.array_equal(s, xe.eval_shapes(a, 16, 8))
    space = xe.shape_space(b)
    assert space.names == ("height", "thickness")
    assert (s >= space.low_array).all() and (s <= space.high_array).all()
    with pytest.raises(ValueError, match="shapes = 0"):
        xe.eval_shapes(a, 0)


def test_set_shape_keeps_the_state_and_moves_the_reference_under_the_character(shaped) -> None:
    env = _walk_env(shaped)
    qpos, qvel = env.qpos.copy(), env.data.qvel[: env.nv].copy()
    mujoco_low = extent(env.model, env.data, 2, env.bodies)[0]
    target = env.scheduler.frame(0).qpos.copy()
    status = env.scheduler.status()
    old_model, k = env.model, env.k
    env.set_shape([1.4, 1.2])
    assert env.model is not old_model and env.k == k
    np.testing.assert_array_equal(env.params, [1.4, 1.2])
    np.testing.assert_allclose(env.qpos[3:], qpos[3:])  # orientation and joint angles carried over
    np.testing.assert_allclose(env.qpos[:2], qpos[:2])
    np.testing.assert_allclose(env.data.qvel[: env.nv], qvel)
    assert env.qpos[2] > qpos[2] + 0.1  # taller legs: the root rises, the lowest point stays
    assert extent(env.model, env.data, 2, env.bodies)[0] == pytest.approx(max(mujoco_low, 0.0), abs=0.02)
    new_target = env.scheduler.frame(0).qpos
    np.testing.assert_allclose(new_target[:2], target[:2], atol=1e-9)  # the target root stays where it was
    assert new_target[2] > target[2] + 0.1  # ... at the new body's height
    assert env.scheduler.status()["clip_time_s"] == status["clip_time_s"]
    assert env.leg_ratio > 1.2
    obs = env.observe_now()
    np.testing.assert_allclose(obs[:2], [1.4, 1.2])  # the shape first in the observation
    obs, _, _, _, info = env.step(np.zeros(env.act_dim))
    assert np.isfinite(obs).all() and not info["diverged"] and info["body_error_m"] < 0.5


def test_set_shape_refuses_bad_values_and_bodies_that_do_not_vary(shaped, fixed) -> None:
    env = _walk_env(shaped, 2)
    before = env.model
    with pytest.raises(ValueError, match="height"):
        env.set_shape([9.0, 1.0])
    assert env.model is before
    loaded = checkpoint.load_trained(fixed)
    base = xe.make_eval_env(loaded, [])
    base.reset(0, base.space.default_array, clip_id=CLIP, start_s=0.0)
    with pytest.raises(ValueError, match="does not vary"):
        base.set_shape([1.0, 1.0])


def test_the_keyboard_scheduler_follows_a_body_change(shaped) -> None:
    from common.tasks.executor.schedulers.factory import make_scheduler

    env = _walk_env(shaped, 0)
    s = make_scheduler("keyboard", env)
    env.use_scheduler(s)
    env.reset(0, env.space.default_array)
    for _ in range(5):
        env.step(np.zeros(env.act_dim))
    short = s.frame(0).qpos[2]
    env.set_shape([1.4, 1.0])
    assert s.frame(0).qpos[2] > short + 0.1  # the generator's poses are the new body's
    for _ in range(5):
        _, _, _, _, info = env.step(np.zeros(env.act_dim))
    assert not info["diverged"]
    stitch = make_scheduler("stitch", env)
    env.use_scheduler(stitch)
    env.reset(0, env.space.default_array)
    with pytest.raises(ValueError, match="StitchScheduler cannot follow a body change"):
        env.set_shape([1.2, 1.0])


@pytest.mark.parametrize("which", ["shaped", "fixed"])
def test_evaluate_with_shapes_writes_records_summary_and_map(which, shaped, fixed, tmp_path, capsys) -> None:
    run = shaped if which == "shaped" else fixed
    out = tmp_path / "ev"
    assert report.main(["--checkpoint", str(run), "--clips", CLIP, "humanoid3d_run", "--starts", "2", "--shapes", "3",
                        "--seed", "11", "--no-render", "--out", str(out)]) == 0
    res = json.loads((out / "results.json").read_text())
    eps = res["episodes"]
    assert len(eps) == 2 * 2 * 3
    shapes = xe.eval_shapes(checkpoint.load_trained(run).cfg.task, 3, 11)
    for r in eps:
        np.testing.assert_allclose(r["shape"], shapes[r["shape_index"]])
    assert {(r["clip_id"], r["start_s"]) for r in eps if r["shape_index"] == 2} == {(r["clip_id"], r["start_s"])
                                                                                for r in eps if r["shape_index"] == 0}
    sh = res["summary"]["shapes"]
    assert sh["count"] == 3 and [p["index"] for p in sh["per_shape"]] == [0, 1, 2]
    assert all(p["episodes"] == 4 for p in sh["per_shape"])
    assert set(res["summary"]["splits"]) == {"train", "test"} and res["summary"]["classes"]
    assert res["meta"]["shape_seed"] == 11 and res["meta"]["map_params"] == ["height", "thickness"]
    assert set(sh["map"]) == {"all", "locomotion"}
    assert (out / "shape_map.png").stat().st_size > 10_000
    md = (out / "summary.md").read_text()
    assert "3 shapes drawn uniformly (numpy `default_rng(11)`" in md and "height [0.75, 1.5] (base 1)" in md
    assert "## By body shape" in md
    assert ("**Zero-shot**" in md) == (which == "fixed")
    assert "over 3 shapes (seed 11" in capsys.readouterr().out


def test_shape_options_are_refused_where_they_do_not_act(shaped, capsys) -> None:
    for argv, says in ((["--seed", "3"], "--seed: --shapes N options"),
                       (["--shapes", "2", "--map-params", "height", "nope"], "--map-params height nope"),
                       (["--strength", "0.5"], "--strength: --morph options"),
                       (["--morph", "--shapes", "2"], "--shapes: not options of --morph")):
        with pytest.raises(SystemExit) as exc:
            report.main(["--checkpoint", str(shaped), *argv])
        assert exc.value.code == 2
        assert says in capsys.readouterr().err


def test_morph_changes_the_body_while_it_tracks(shaped, tmp_path, capsys) -> None:
    out = tmp_path / "morph"
    assert report.main(["--checkpoint", str(shaped), "--morph", "--clips", CLIP, "--schedule",
                        '[[0, {}], [0.5, {"height": 1.3}], [1, {"thickness": 0.7}]]', "--every", "2",
                        "--out", str(out)]) == 0
    res = json.loads((out / "morph.json").read_text())
    m, b = res["morph"], res["base_body"]
    assert m["morphs"] == 30 and b["morphs"] == 0  # every 2nd of 60 steps changed the body
    assert m["shapes"][-1][1] == pytest.approx([1.0, 0.7])
    assert m["steps"] == b["steps"] == 60 and not m["diverged"]
    assert (out / "morph.png").is_file()
    assert "30 body changes over 1.0 s" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        report.main(["--checkpoint", str(shaped), "--morph", "--schedule", '[[0, {}], [1, {"nope": 1.2}]]',
                     "--out", str(out)])
    assert "'nope' is not one of" in capsys.readouterr().err


def test_robustness_has_a_shape_row(shaped, fixed, tmp_path) -> None:
    for run in (shaped, fixed):
        out = tmp_path / run.name
        assert robustness.main(["--checkpoint", str(run), "--rows", "shape", "--shapes", "2", "--starts", "1",
                                "--clips", CLIP, "--out", str(out)]) == 0
        res = json.loads((out / "robustness.json").read_text())
        (row,) = res["rows"]
        assert row["group"] == "shape" and row["row"] == "2 random shapes (seed 2019)"
        assert len(row["episodes"]) == 2 and {e["shape_index"] for e in row["episodes"]} == {0, 1}
        assert row["relative"] == pytest.approx(row["performance"] / res["unperturbed"]["performance"])
        assert res["meta"]["protocol"]["shape"]["trained_on_shapes"] == (run == shaped)
        assert "**The shape row**" in (out / "robustness.md").read_text()
    assert robustness.row_groups("mass,shape") == ("mass", "shape")


def test_the_clip_rotation_is_balanced_seeded_and_covers_every_clip() -> None:
    ids = [c for c, _ in humanoid_clips(library="full")]
    assert len(ids) > 400  # the library: the case the rotation is for
    n, k = 300, 8
    pairs = xe.shape_clip_assignment(ids, n, k, 7)
    assert len(pairs) == n and all(len(p) == len(set(p)) == k for p in pairs)
    runs = Counter(c for p in pairs for c in p)
    assert set(runs) == set(ids)  # every clip runs ...
    lo = n * k // len(ids)
    assert set(runs.values()) <= {lo, lo + 1} and sum(runs.values()) == n * k  # ... on floor or ceil of N K / C shapes
    assert xe.shape_clip_assignment(ids, n, k, 7) == pairs  # deterministic per seed
    assert xe.shape_clip_assignment(list(reversed(ids)), n, k, 7) == pairs  # the clip set counts, not its order
    assert xe.shape_clip_assignment(ids, n, k, 8) != pairs
    assert xe.shape_clip_assignment(ids, n + 5, k, 7)[:n] == pairs  # more shapes keep the first ones' clips
    few = xe.shape_clip_assignment(ids, 3, 2, 7)  # N K < C: 6 distinct clips, one shape each
    assert len({c for p in few for c in p}) == 6
    everything = [tuple(ids)] * 4
    assert xe.shape_clip_assignment(ids, 4, 0, 7) == everything == xe.shape_clip_assignment(ids, 4, len(ids) + 3, 7)
    with pytest.raises(ValueError, match="clips per shape = -1"):
        xe.shape_clip_assignment(ids, 4, -1, 7)
    clips = [xe.EvalClip(c, "root", "train") for c in ids[:5]]
    durations = {c.clip_id: 2.0 for c in clips}
    full = xe.episode_jobs(clips, durations, 2, 3)
    assert xe.episode_jobs(clips, durations, 2, 3, [tuple(ids[:5])] * 3) == full  # every clip: today's jobs exactly
    some = xe.episode_jobs(clips, durations, 2, 3, [(ids[0],), (ids[1], ids[0]), (ids[4],)])
    assert [(cid, j) for _, cid, _, j in some[::2]] == [(ids[0], 0), (ids[0], 1), (ids[1], 1), (ids[4], 2)]
    assert [job[0] for job in some] == list(range(8))


def test_worst_decile_ranks_the_shapes_per_split() -> None:
    def rec(j, split, ok):
        return {"shape_index": j, "split": split, "success": ok}

    records = [rec(j, "train", j % 2 == 0) for j in range(20)] + [rec(j, "test", j < 5) for j in range(10)]
    w = xe.worst_decile(records)
    # overall: 8 shapes at 0% (5, 7, 9 failed both splits; 11, ..., 19 train only): 2 of 20, ties by index
    assert w["overall"] == {"success_pct": 0.0, "shapes": [5, 7], "of": 20, "neighbours": 1}
    assert w["train"] == {"success_pct": 0.0, "shapes": [1, 3], "of": 20, "neighbours": 1}
    assert w["test"] == {"success_pct": 0.0, "shapes": [5], "of": 10, "neighbours": 1}  # the 10 shapes that ran a test clip
    mixed = [rec(0, "train", True), rec(0, "train", False), rec(1, "train", True)]
    assert xe.worst_decile(mixed)["train"] == {"success_pct": 50.0, "shapes": [0], "of": 2, "neighbours": 1}


def test_the_worst_decile_reads_the_map_over_each_shapes_neighbours() -> None:
    """With a box, the map at a shape pools its NEIGHBOUR_SHARE nearest shapes: a region that
    fails is found, a lone unlucky shape in a good region is not, and the figure is not the
    0% every few-episode shape would give."""
    space = ParamSpace(names=("height", "thickness"), low=(0.0, 0.0), high=(1.0, 1.0), default=(0.5, 0.5))
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 1, (200, 2))
    records = []
    for j, (x, y) in enumerate(pts):
        p_ok = 0.1 if x < 0.2 else 0.9  # the thin strip x < 0.2 is where the policy fails
        for _ in range(4):
            records.append({"shape_index": j, "split": "train", "success": bool(rng.uniform() < p_ok or j == 7),
                            "shape": [float(x), float(y)]})
    alone = xe.worst_decile(records)["train"]
    mapped = xe.worst_decile(records, space)["train"]
    assert alone["success_pct"] == 0.0 and alone["neighbours"] == 1
    assert mapped["neighbours"] == xe.share_count(xe.NEIGHBOUR_SHARE, 200) == 10
    assert 0.0 < mapped["success_pct"] < 30.0
    assert all(pts[j, 0] < 0.3 for j in mapped["shapes"])  # the decile lies in the failing strip


def test_evaluate_runs_k_clips_per_shape_on_the_assigned_pairs(shaped, tmp_path, capsys) -> None:
    out = tmp_path / "pairs"
    assert report.main(["--checkpoint", str(shaped), "--clips", CLIP, "humanoid3d_run", "--starts", "2", "--shapes", "3",
                        "--clips-per-shape", "1", "--seed", "11", "--no-render", "--out", str(out)]) == 0
    res = json.loads((out / "results.json").read_text())
    eps, meta = res["episodes"], res["meta"]
    pairs = xe.shape_clip_assignment([CLIP, "humanoid3d_run"], 3, 1, 11)
    assert len(eps) == 3 * 2  # 3 shapes x 1 clip x 2 starts
    assert meta["clips_per_shape"] == 1 and meta["shape_clips"] == [list(p) for p in pairs]
    assert sorted((r["shape_index"], r["clip_id"]) for r in eps) == sorted((j, p[0]) for j, p in enumerate(pairs) for _ in "ab")
    shapes = xe.eval_shapes(checkpoint.load_trained(shaped).cfg.task, 3, 11)  # the same bodies as without the flag
    for r in eps:
        np.testing.assert_allclose(r["shape"], shapes[r["shape_index"]])
    sh = res["summary"]["shapes"]
    assert all(p["episodes"] == 2 for p in sh["per_shape"])
    per_shape = {p["index"]: p["success_pct"] for p in sh["per_shape"]}
    worst = sh["worst_decile_shape_success_pct"]
    assert set(worst) == {"overall", "train", "test"}
    assert worst["overall"] == pytest.approx(min(per_shape.values()))  # 10% of 3 shapes: the worst one
    assert sh["worst_decile_shapes"]["train"]["of"] == sum(p == (CLIP,) for p in pairs)
    assert res["summary"]["zero_action_ceiling"]["episodes"] == 6  # the same jobs
    assert set(sh["map"]) >= {"all"}
    md = (out / "summary.md").read_text()
    assert "each of 3 shapes runs 1 of the 2 selected clips (`--clips-per-shape 1`)" in md
    assert "`default_rng([11, 1])`" in md and "every clip on 1-2 shapes" in md
    assert "**Worst decile of the success map**" in md and f"all **{worst['overall']:.1f}%** (1 of 3 shapes)" in md
    assert "worst decile of shapes all" in capsys.readouterr().out


def test_a_bad_clips_per_shape_exits_2_naming_it(shaped, capsys) -> None:
    for argv, says in ((["--clips-per-shape", "-1", "--shapes", "2"], "--clips-per-shape = -1 is not allowed: give"),
                       (["--clips-per-shape", "2"], "--clips-per-shape = 2 is not allowed without --shapes"),
                       (["--clips-per-shape", "two", "--shapes", "2"], "--clips-per-shape"),
                       (["--morph", "--shapes", "2", "--clips-per-shape", "1"], "--clips-per-shape: not options of --morph")):
        with pytest.raises(SystemExit) as exc:
            report.main(["--checkpoint", str(shaped), *argv])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert says in err and len(err.strip().splitlines()) == 1, err
