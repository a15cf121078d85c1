"""The swimmers' fitted stroke speed (`learner.tools.stroke_fit`): the fit recovers a known
law, bad model files are refused by name, and under `swimmer_speed = "stroke_fit"` a real
manta's target speed is its length-scaled target times the model's ratio for its shape (also
after a shape change), with the evaluation's speed error against both targets."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from common.tasks.shape.config import ImitateConfig
from common.tasks.registry import make_env, task_space
from common.tasks.shape.env import stroke_model_for as model_for
from common.tasks.shape.stroke_model import StrokeModel, StrokeModelError
from learner.tools.stroke_fit import cross_validated_rms, fit, ridge_fit
from learner.config import RunConfig
from learner.evaluation.shape.swim_metrics import SwimTracker, target_rule
from learner.presets import PRESETS


def test_ridge_fit_recovers_a_power_law() -> None:
    rng = np.random.default_rng(0)
    params = rng.uniform(0.5, 1.5, size=(300, 4))
    w_true = np.array([0.8, -0.5, 0.0, 0.3])
    ratios = np.exp(0.1 + np.log(params) @ w_true + rng.normal(0.0, 0.01, 300))
    summary = fit(params, ratios)
    assert np.allclose(summary["weights"], w_true, atol=0.02)
    assert summary["bias"] == pytest.approx(0.1, abs=0.01)
    assert summary["cv_rms_log"] < 0.02  # the noise is 1%
    _, w = ridge_fit(np.log(params), np.log(ratios), lam=1e6)  # a huge ridge flattens the weights
    assert np.abs(w).max() < 0.01 and cross_validated_rms(np.log(params), np.log(ratios), 1e6) > 0.1


def _write(path: Path, **doc) -> Path:
    path.write_text(json.dumps(doc))
    return path


def _model(tmp_path: Path, **changes) -> Path:
    doc = {"preset": "manta", "names": ["a", "b"], "bias": 0.5, "weights": [1, 0], "clamp": [0.25, 4.0], **changes}
    return _write(tmp_path / "m.json", **doc)


def test_bad_model_files_are_refused_by_name(tmp_path: Path) -> None:
    names = ("a", "b")
    with pytest.raises(StrokeModelError, match="not found.*stroke-fit manta"):
        StrokeModel.load("manta", names, tmp_path / "missing.json")
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(StrokeModelError, match="not readable JSON"):
        StrokeModel.load("manta", names, tmp_path / "junk.json")
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(StrokeModelError, match="not readable JSON"):
        StrokeModel.load("manta", names, tmp_path / "deep.json")
    with pytest.raises(StrokeModelError, match="needs an object with preset, names, bias, weights and clamp"):
        StrokeModel.load("manta", names, _write(tmp_path / "m.json", preset="manta", names=list(names)))
    with pytest.raises(StrokeModelError, match="is for 'fish'"):
        StrokeModel.load("manta", names, _model(tmp_path, preset="fish"))
    with pytest.raises(StrokeModelError, match="weights has 1 entries; give a list of 2 numbers"):
        StrokeModel.load("manta", names, _model(tmp_path, weights=[0]))
    with pytest.raises(StrokeModelError, match=r"weights\[1\] = '0' must be a number"):
        StrokeModel.load("manta", names, _model(tmp_path, weights=[1, "0"]))
    with pytest.raises(StrokeModelError, match="bias = True must be a number"):
        StrokeModel.load("manta", names, _model(tmp_path, bias=True))
    (tmp_path / "big.json").write_text(_model(tmp_path).read_text().replace('"bias": 0.5', '"bias": ' + "9" * 400))
    with pytest.raises(StrokeModelError, match="bias = 9+ must be finite"):
        StrokeModel.load("manta", names, tmp_path / "big.json")
    (tmp_path / "nan.json").write_text(_model(tmp_path).read_text().replace('"bias": 0.5', '"bias": NaN'))
    with pytest.raises(StrokeModelError, match="bias = nan must be finite"):
        StrokeModel.load("manta", names, tmp_path / "nan.json")
    with pytest.raises(StrokeModelError, match=r"clamp = \[0.0, 4.0\] must satisfy 0 < low <= high"):
        StrokeModel.load("manta", names, _model(tmp_path, clamp=[0, 4]))
    m = StrokeModel.load("manta", names, _model(tmp_path))
    assert m.ratio(np.array([2.0, 3.0])) == pytest.approx(2.0 * np.exp(0.5))
    assert m.ratio(np.array([1e9, 1.0])) == 4.0 and m.ratio(np.array([1e-9, 1.0])) == 0.25  # held to the fitted range
    assert len(m.digest) == 12


def test_an_unknown_speed_rule_is_refused() -> None:
    with pytest.raises(ValueError, match="swimmer-speed = 'fast': give length, stroke_fit"):
        ImitateConfig(swimmer_speed="fast")


def test_which_tasks_load_a_model() -> None:
    manta = PRESETS["manta"][1].task
    assert manta.imitate.swimmer_speed == "stroke_fit"
    assert isinstance(model_for(manta), StrokeModel)  # the shipped model fits the preset's parameters
    assert model_for(PRESETS["manta-nonorm"][1].task) is None  # no normalization: the target is not scaled
    assert model_for(PRESETS["fish"][1].task) is None  # the fish keeps the length rule
    walker = PRESETS["lower_biped"][1].task
    with pytest.raises(ValueError, match="'lower_biped' is not a swimmer"):
        model_for(dataclasses.replace(walker, imitate=dataclasses.replace(walker.imitate, swimmer_speed="stroke_fit")))
    old = json.loads(PRESETS["manta"][1].to_json())
    del old["task"]["imitate"]["swimmer_speed"]  # a checkpoint's config from before the rule existed
    assert RunConfig.from_json(json.dumps(old)).task.imitate.swimmer_speed == "length"


def _manta_envs(shape: np.ndarray) -> dict:
    task = PRESETS["manta"][1].task
    envs = {rule: make_env(dataclasses.replace(task, imitate=dataclasses.replace(task.imitate, swimmer_speed=rule)), seed=0)
            for rule in ("length", "stroke_fit")}
    for env in envs.values():
        env.reset(0, shape)
    return envs


def test_a_manta_asks_for_its_own_stroke_speed() -> None:
    space = task_space(PRESETS["manta"][1].task)
    shape = np.random.default_rng(3).uniform(space.low_array, space.high_array)
    envs = _manta_envs(shape)
    ratio = StrokeModel.load("manta", space.names).ratio(shape)
    assert ratio != pytest.approx(1.0, abs=0.02)  # a random shape's stroke does not swim at the length rule's speed
    assert envs["stroke_fit"].target_velocity() == pytest.approx(ratio * envs["length"].target_velocity())
    # the evaluation's speed error against both targets, on a hand-made velocity: the length rule's target
    env = envs["stroke_fit"]
    v = envs["length"].target_velocity()
    env.com_hist.clear()
    for i in range(env.com_hist.maxlen):
        env.com_hist.append(np.array([v[0], v[1], 0.0]) * i * env.dt)
    tracker = SwimTracker()
    tracker(env, k=100)
    r = tracker.result()
    assert r["swim_speed_error_length_pct"] == pytest.approx(0.0, abs=1e-6)
    assert r["swim_speed_error_pct"] == pytest.approx(100.0 * abs(1.0 / ratio - 1.0))
    assert target_rule(env) == f"stroke_fit {env.stroke_model.digest}" and target_rule(envs["length"]) == "length"
    # a shape change mid-episode takes the new shape's target
    other = np.random.default_rng(4).uniform(space.low_array, space.high_array)
    env.set_shape(other)
    assert env.norm.speed_factor == pytest.approx(env.stroke_model.ratio(other))


def test_the_fit_command_refuses_bad_input_by_name(tmp_path: Path, capsys) -> None:
    from learner.tools import stroke_fit

    def fails(*argv: str) -> str:
        with pytest.raises(SystemExit) as exc:
            stroke_fit.main(list(argv))
        assert exc.value.code == 2
        return capsys.readouterr().err

    assert "--seed = -1 is not allowed: give an integer in [0, 4294967295]" in fails("manta", "--seed", "-1", "--out", str(tmp_path / "m.json"))
    assert "--shapes = 5 is not allowed: give an integer in [20, 5000]" in fails("manta", "--shapes", "5", "--out", str(tmp_path / "m.json"))
    assert "exists" in fails("manta", "--out", str(_model(tmp_path)))  # no measuring over a model without --force
    assert "holds no readable samples" in fails("manta", "--refit", "--out", str(_model(tmp_path)))
    rows = {"params": [[1.0, 1.0]] * 20, "speed_m_s": [0.3] * 20, "target_m_s": [0.3] * 20}
    bad = _model(tmp_path, samples={**rows, "speed_m_s": ["fast"] * 20})
    assert "holds no readable samples" in fails("manta", "--refit", "--out", str(bad))
    bad = _model(tmp_path, samples=rows, base_ratio="1.0")
    assert "base_ratio = '1.0' must be a positive number" in fails("manta", "--refit", "--out", str(bad))
