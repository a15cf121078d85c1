"""The swimmers' fitted stroke speed (`common.tasks.stroke_fit`): the fit recovers a known
law, bad model files are refused by name, and under `swimmer_speed = "stroke_fit"` a real
manta's target speed is its length-scaled target times the model's ratio for its shape."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from common.tasks.imitate_config import ImitateConfig
from common.tasks.registry import make_env, task_space
from common.tasks.stroke_fit import MODEL_DIR, StrokeModel, StrokeModelError, cross_validated_rms, fit, ridge_fit
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


def test_bad_model_files_are_refused_by_name(tmp_path: Path) -> None:
    names = ("a", "b")
    with pytest.raises(StrokeModelError, match="not found.*stroke_fit manta"):
        StrokeModel.load("manta", names, tmp_path / "missing.json")
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(StrokeModelError, match="not readable JSON"):
        StrokeModel.load("manta", names, tmp_path / "junk.json")
    with pytest.raises(StrokeModelError, match="needs preset, names, bias and weights"):
        StrokeModel.load("manta", names, _write(tmp_path / "m.json", preset="manta", names=list(names)))
    with pytest.raises(StrokeModelError, match="is for 'fish'"):
        StrokeModel.load("manta", names, _write(tmp_path / "m.json", preset="fish", names=list(names), bias=0, weights=[0, 0]))
    with pytest.raises(StrokeModelError, match="must be finite"):
        StrokeModel.load("manta", names, _write(tmp_path / "m.json", preset="manta", names=list(names), bias=0, weights=[0]))
    m = StrokeModel.load("manta", names, _write(tmp_path / "m.json", preset="manta", names=list(names), bias=0.5, weights=[1, 0]))
    assert m.ratio(np.array([2.0, 3.0])) == pytest.approx(2.0 * np.exp(0.5))


def test_an_unknown_speed_rule_is_refused() -> None:
    with pytest.raises(ValueError, match="swimmer-speed = 'fast': give length, stroke_fit"):
        ImitateConfig(swimmer_speed="fast")


@pytest.mark.skipif(not (MODEL_DIR / "manta.json").exists(), reason="the shipped manta model is made by stroke_fit")
def test_a_manta_asks_for_its_own_stroke_speed() -> None:
    task = PRESETS["manta"][1].task
    space = task_space(task)
    shape = np.random.default_rng(3).uniform(space.low_array, space.high_array)
    envs = {rule: make_env(dataclasses.replace(task, imitate=dataclasses.replace(task.imitate, swimmer_speed=rule)), seed=0)
            for rule in ("length", "stroke_fit")}
    for env in envs.values():
        env.reset(0, shape)
    model = StrokeModel.load("manta", space.names)
    ratio = model.ratio(shape)
    assert ratio != pytest.approx(1.0, abs=0.02)  # a random shape's stroke does not swim at the length rule's speed
    assert envs["stroke_fit"].target_velocity() == pytest.approx(ratio * envs["length"].target_velocity())
