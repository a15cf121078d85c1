"""Pick MuJoCo's offscreen OpenGL backend from what this machine has.

MuJoCo chooses its GL backend from `MUJOCO_GL` when it is first imported, and with
`MUJOCO_GL=osmesa` or `egl` that import itself fails when the library is missing. Ray workers
inherit the driver's environment, so a wrong default set by one module used to kill every
rollout actor of `python -m learner.main` on a machine without libOSMesa. The rules:

- an explicit `MUJOCO_GL` always wins (the user's choice);
- with a display, nothing is set (MuJoCo uses GLFW);
- without one, EGL if `libEGL` is installed (Mesa's EGL renders headless), else OSMesa if
  `libOSMesa` is, else nothing: simulation works and only rendering reports a missing GL.
"""

from __future__ import annotations

import ctypes.util
import os

BACKEND_LIBRARIES = (("egl", "EGL"), ("osmesa", "OSMesa"))


def available_backend() -> str | None:
    """The first offscreen backend whose shared library the dynamic linker can find."""
    for backend, library in BACKEND_LIBRARIES:
        if ctypes.util.find_library(library):
            return backend
    return None


def choose_offscreen_gl() -> str | None:
    """Set `MUJOCO_GL` (and PyOpenGL's platform) for a headless machine, before mujoco's first
    import; returns the backend in effect (None: GLFW or none)."""
    if "MUJOCO_GL" in os.environ:
        return os.environ["MUJOCO_GL"]
    if os.environ.get("DISPLAY"):
        return None
    backend = available_backend()
    if backend is not None:
        os.environ["MUJOCO_GL"] = backend
        os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    return backend


def use_offscreen_context() -> None:
    """For a process that imported mujoco before `choose_offscreen_gl` ran (mujoco then picked
    GLFW) and has no display: point mujoco's renderer at the available offscreen context."""
    import mujoco.rendering.classic.gl_context as gl_context

    if os.environ.get("DISPLAY") or getattr(gl_context, "_MUJOCO_GL", "x") not in ("", "glfw"):
        return
    backend = available_backend()
    if backend is None:
        raise RuntimeError("no display and no offscreen OpenGL: install Mesa's EGL (Debian: libegl1 libegl-mesa0 "
                           "libgl1-mesa-dri) or libosmesa6, or set MUJOCO_GL")
    os.environ["PYOPENGL_PLATFORM"] = backend
    if backend == "egl":
        from mujoco.egl import GLContext
    else:
        from mujoco.osmesa import GLContext
    gl_context.GLContext = GLContext
