"""Pick MuJoCo's offscreen OpenGL backend from what this machine has, right before a renderer is
made, whatever was imported first.

`import mujoco` reads `MUJOCO_GL` once and keeps the matching `GLContext` class in
`mujoco.rendering.classic.gl_context` (GLFW when it is unset); `mujoco.Renderer` looks that
class up each time one is made. So every renderer of the project is made right after
`use_offscreen_context()`, which sets `MUJOCO_GL` if it is unset and, if mujoco was imported
before that, swaps in the chosen backend's `GLContext`. The rules:

- an explicit `MUJOCO_GL` always wins (the user's choice);
- with a display, nothing is set (MuJoCo uses GLFW);
- without one, EGL if `libEGL` is installed (Mesa's EGL renders headless), else OSMesa if
  `libOSMesa` is, else nothing: simulation works and rendering raises, naming what to install.
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
    """Set `MUJOCO_GL` (and PyOpenGL's platform) for a headless machine if it is unset; returns
    the backend in effect (None: GLFW or none)."""
    if "MUJOCO_GL" in os.environ:
        return os.environ["MUJOCO_GL"]
    if os.environ.get("DISPLAY"):
        return None
    backend = available_backend()
    if backend is not None:
        os.environ["MUJOCO_GL"] = backend
        os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    return backend


def use_offscreen_context() -> str | None:
    """Make the next `mujoco.Renderer` use the backend `choose_offscreen_gl` picks, whether mujoco
    was imported before or after; returns that backend (None: GLFW). Call it right before
    making a renderer. RuntimeError when there is neither a display nor an offscreen GL."""
    chosen = choose_offscreen_gl()
    backend = chosen.strip().lower() if chosen else None
    # lazy: after MUJOCO_GL is set above, so a first import of mujoco takes the chosen backend
    import mujoco.rendering.classic.gl_context as gl_context

    if backend is None and not os.environ.get("DISPLAY"):
        raise RuntimeError("no display and no offscreen OpenGL: install Mesa's EGL (Debian: libegl1 libegl-mesa0 "
                           "libgl1-mesa-dri) or libosmesa6, or set MUJOCO_GL")
    if backend not in ("egl", "osmesa"):
        return chosen
    if getattr(getattr(gl_context, "GLContext", None), "__module__", None) == f"mujoco.{backend}":
        return backend  # mujoco was imported after the choice and took it
    # mujoco was imported before MUJOCO_GL was set and took GLFW: swap in the offscreen context
    os.environ["PYOPENGL_PLATFORM"] = backend
    if backend == "egl":
        from mujoco.egl import GLContext  # lazy: needs PYOPENGL_PLATFORM set above; EGL is not on every machine
    else:
        from mujoco.osmesa import GLContext  # lazy: needs PYOPENGL_PLATFORM set above; OSMesa is not on every machine
    gl_context.GLContext = GLContext
    return backend
