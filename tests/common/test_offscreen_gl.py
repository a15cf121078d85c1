"""The offscreen GL choice: never a backend this machine lacks (a missing one kills `import mujoco`)."""

import os
import subprocess
import sys

from common import offscreen_gl


def test_headless_import_picks_an_installed_backend():
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY")}
    code = "import common.characters, mujoco, os; print(os.environ.get('MUJOCO_GL'))"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == str(offscreen_gl.available_backend())


def test_nothing_installed_sets_nothing(monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.setattr(offscreen_gl.ctypes.util, "find_library", lambda name: None)
    assert offscreen_gl.choose_offscreen_gl() is None
    assert "MUJOCO_GL" not in os.environ


def test_explicit_choice_and_display_win(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "glfw")
    assert offscreen_gl.choose_offscreen_gl() == "glfw"
    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setenv("DISPLAY", ":0")
    assert offscreen_gl.choose_offscreen_gl() is None
    assert "MUJOCO_GL" not in os.environ
