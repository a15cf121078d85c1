"""`morphmimic play --shape` and the live session's shape change on an executor trained over body
shapes (issue 55 item 4): a tiny executor really trained with `--task.body.vary-shape`, real
MuJoCo, a real H.264 file read back."""

from __future__ import annotations

import numpy as np
import pytest

from learner.live import play
from learner.live.session import LiveSession
from tests.learner.evaluation.executor_checkpoints import tiny_executor, tiny_shape_executor


@pytest.fixture(scope="module")
def shaped(tmp_path_factory):
    return str(tiny_shape_executor(tmp_path_factory.mktemp("shape")))


def test_play_shape_builds_that_body_and_films_it(shaped, tmp_path, capsys) -> None:
    import imageio.v3 as iio

    tall = LiveSession(shaped, clip="humanoid3d_walk", shape={"height": 1.3})
    base = LiveSession(shaped, clip="humanoid3d_walk")
    np.testing.assert_allclose(tall.params, [1.3, 1.0])
    np.testing.assert_allclose(tall.env.params, [1.3, 1.0])
    assert tall.body_height_m() > 1.2 * base.body_height_m()
    out = tmp_path / "tall.mp4"
    assert play.main(["--checkpoint", shaped, "--clip", "humanoid3d_walk", "--shape", "height=1.3", "--seconds", "0.5",
                      "--fps", "8", "--width", "96", "--height", "64", "--out", str(out)]) == 0
    assert iio.imread(out, plugin="FFMPEG").shape == (4, 64, 96, 3)
    capsys.readouterr()
    assert play.main(["--checkpoint", shaped, "--shape", "height=9"]) == 2
    assert capsys.readouterr().err.strip() == "morphmimic play: shape parameter height = 9.0 is outside [0.75, 1.5]"
    assert play.main(["--checkpoint", shaped, "--shape", "global_z=1.2"]) == 2
    assert "'global_z' is not one of height, thickness" in capsys.readouterr().err


def test_the_session_reshapes_the_executor_live(shaped) -> None:
    s = LiveSession(shaped, clip="humanoid3d_walk", seed=0)
    assert s.shape_can_change and "tall" in s.body_presets() and "thin" in s.body_presets()
    for _ in range(5):
        s.step()
    before, model = s.body_height_m(), s.env.model
    s.set_shape({"height": 1.4})
    assert s.env.model is not model and s.body_height_m() > before + 0.3
    np.testing.assert_allclose(s.obs[:2], [1.4, 1.0])
    assert s.status()["shape"] == {"height": 1.4, "thickness": 1.0}
    steps, resets = s.steps, s.resets
    for _ in range(3):
        s.step()
    assert s.steps == steps + 3 and s.resets == resets  # tracking goes on, not a reset
    with pytest.raises(ValueError, match=r"shape parameter thickness = 2.0 is outside \[0.5, 1.5\]"):
        s.set_shape({"thickness": 2.0})
    assert s.status()["shape"] == {"height": 1.4, "thickness": 1.0}


def test_a_base_body_executor_refuses_a_shape_by_name(tmp_path, capsys) -> None:
    run = str(tiny_executor(tmp_path, "xbase", actuation="pd"))
    with pytest.raises(ValueError, match="cannot change shape .*trained on the base humanoid only"):
        LiveSession(run, shape={"height": 1.2})
    assert play.main(["--checkpoint", run, "--shape", "height=1.2"]) == 2
    assert "cannot change shape" in capsys.readouterr().err


def test_the_studio_opens_on_the_body_given(shaped, capsys) -> None:
    from learner.live import studio
    from learner.live.studio_core import StudioCore

    core = StudioCore(shaped, clip="humanoid3d_walk", shape={"height": 1.3})
    np.testing.assert_allclose(core.session.params, [1.3, 1.0])
    assert core.session.status()["shape"] == {"height": 1.3, "thickness": 1.0}
    assert studio.main(["--checkpoint", shaped, "--shape", "height=9", "--seconds", "1", "--port", "0"]) == 2
    assert "shape parameter height = 9.0 is outside [0.75, 1.5]" in capsys.readouterr().err
