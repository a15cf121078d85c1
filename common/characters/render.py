"""Offscreen PNG of a character with MuJoCo's renderer.

A machine without a display needs an offscreen GL: `MUJOCO_GL=egl` (GPU or Mesa's EGL;
packages libegl1 + libgl1-mesa-dri) or `MUJOCO_GL=osmesa` (software; package libosmesa6);
`common.offscreen_gl.use_offscreen_context` picks whichever this machine has, right before the
renderer is made.
"""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import mujoco
import numpy as np

from common.characters.character import extent
from common.offscreen_gl import use_offscreen_context


def render_png(ch, path: str | Path | None = None, data=None, width: int = 640, height: int = 480,
               azimuth_deg: float = 135.0, elevation_deg: float | None = None):
    """Render `ch` (a Character) at `data` (default: its standing pose) from a free camera that
    frames the whole body (elevation default: -15 deg, -35 for swimmers so their flat bodies
    show); write a PNG to `path` if given. Returns the image [H, W, 3] uint8."""
    use_offscreen_context()
    model = ch.model
    data = ch.make_data() if data is None else data
    lo = np.array([extent(model, data, a)[0] for a in range(3)])
    hi = np.array([extent(model, data, a)[1] for a in range(3)])
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = (lo + hi) / 2.0
    cam.distance = 1.6 * float(np.linalg.norm(hi - lo)) + 0.3
    cam.azimuth = azimuth_deg
    cam.elevation = elevation_deg if elevation_deg is not None else (-35.0 if ch.is_swimmer else -15.0)
    with mujoco.Renderer(model, height=height, width=width) as renderer:
        renderer.update_scene(data, camera=cam)
        image = renderer.render()
    if path is not None:
        iio.imwrite(str(path), image)
    return image
