"""The offscreen GL choice: never a backend this machine lacks, and the same whatever module
imported mujoco first (the choice is made right before a renderer is)."""

import os
import subprocess
import sys

import pytest

from common import offscreen_gl

# Both of the project's render paths: a clip strip (common.motion.view, a stand-in motion that
# holds the standing pose) and a character PNG (common.characters.render).
RENDER = """
import types
import numpy as np
from common.characters import load_character
from common.characters.render import render_png
from common.motion.view import render_frames
ch = load_character("lower_biped")
pose = ch.make_data().qpos.copy()
motion = types.SimpleNamespace(model=ch.model, qpos=lambda t: np.tile(pose, (len(t), 1)))
strip = render_frames(motion, np.zeros(1), width=64, height=48)[0]
image = render_png(ch, width=64, height=48)
from mujoco.rendering.classic import gl_context
print(gl_context.GLContext.__module__, int(strip.std() > 0), int(np.asarray(image).std() > 0))
"""


@pytest.mark.render
@pytest.mark.parametrize("first", ["import mujoco", "import common.characters", "import common.motion.view"])
def test_headless_rendering_uses_an_installed_backend_whatever_is_imported_first(first: str) -> None:
    backend = offscreen_gl.available_backend()
    if backend is None:
        pytest.skip("no offscreen GL (EGL or OSMesa) installed")
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY")}
    out = subprocess.run([sys.executable, "-c", first + "\n" + RENDER], env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == [f"mujoco.{backend}", "1", "1"]


def test_nothing_installed_sets_nothing(monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.setattr(offscreen_gl.ctypes.util, "find_library", lambda name: None)
    assert offscreen_gl.choose_offscreen_gl() is None
    assert "MUJOCO_GL" not in os.environ
    with pytest.raises(RuntimeError, match="no display and no offscreen OpenGL"):
        offscreen_gl.use_offscreen_context()


def test_explicit_choice_and_display_win(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "glfw")
    assert offscreen_gl.choose_offscreen_gl() == "glfw"
    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setenv("DISPLAY", ":0")
    assert offscreen_gl.choose_offscreen_gl() is None
    assert "MUJOCO_GL" not in os.environ
