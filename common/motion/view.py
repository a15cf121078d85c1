"""Replay a clip kinematically on a character and write a PNG strip or an animation.

Kinematic replay: the reference qpos is set and `mj_kinematics` run, no physics, so what the
picture shows is exactly the reference a controller is asked to track. Rendering uses
`mujoco.Renderer` offscreen (without a display, the EGL or OSMesa this machine has, picked by
`common.offscreen_gl.use_offscreen_context`) and imageio to write files: `.png` (a strip of
frames side by side) or `.gif` (an animation; `.mp4` needs the imageio-ffmpeg plugin).
"""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import mujoco
import numpy as np

from common.motion.reference import CharacterMotion
from common.offscreen_gl import use_offscreen_context


def _camera(motion: CharacterMotion, qpos: np.ndarray, distance_m: float) -> mujoco.MjvCamera:
    """A side camera (from -y, the clip's right) looking at the root at half its height; for
    swimmers (no gravity) from above, so a tail beat or a wing flap shows."""
    swimmer = not np.any(motion.model.opt.gravity)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = [qpos[0], qpos[1], qpos[2] if swimmer else 0.5 * max(qpos[2], 0.3)]
    cam.distance = distance_m
    cam.azimuth = 90.0
    cam.elevation = -85.0 if swimmer else -5.0
    return cam


def render_frames(motion: CharacterMotion, times_s: np.ndarray, width: int = 320, height: int = 400,
                  distance_m: float | None = None) -> list[np.ndarray]:
    """RGB images (height, width, 3) uint8 of the reference pose at each time (s)."""
    model = motion.model
    width = min(width, model.vis.global_.offwidth)
    height = min(height, model.vis.global_.offheight)
    data = mujoco.MjData(model)
    qpos_all = motion.qpos(np.asarray(times_s, dtype=np.float64))
    if distance_m is None:
        data.qpos[:] = qpos_all[0]
        mujoco.mj_kinematics(model, data)
        distance_m = 2.2 * max(1.0, float(np.ptp(data.xpos[1:, 2])) + 0.4)
    images = []
    use_offscreen_context()
    with mujoco.Renderer(model, height, width) as renderer:
        opt = mujoco.MjvOption()
        for qpos in qpos_all:
            data.qpos[:] = qpos
            mujoco.mj_kinematics(model, data)
            renderer.update_scene(data, camera=_camera(motion, qpos, distance_m), scene_option=opt)
            images.append(renderer.render().copy())
    return images


def write_strip(motion: CharacterMotion, out: str | Path, n_frames: int = 6, seconds: float | None = None,
                width: int = 240, height: int = 360) -> Path:
    """A PNG of n_frames poses evenly spread over `seconds` (default: the clip), side by side."""
    out = Path(out)
    duration = motion.duration_s if seconds is None else seconds
    times = np.linspace(0.0, duration, n_frames)
    images = render_frames(motion, times, width, height)
    out.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(out, np.concatenate(images, axis=1))
    return out


def write_animation(motion: CharacterMotion, out: str | Path, fps: float = 30.0, seconds: float | None = None,
                    width: int = 320, height: int = 400) -> Path:
    """An animation (.gif, or .mp4 with imageio-ffmpeg) of the clip at `fps` frames per second."""
    out = Path(out)
    duration = motion.duration_s if seconds is None else seconds
    times = np.arange(0.0, duration + 1e-9, 1.0 / fps)
    images = render_frames(motion, times, width, height)
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix.lower() == ".gif":
        iio.imwrite(out, np.stack(images), duration=1000.0 / fps, loop=0)
    else:
        iio.imwrite(out, np.stack(images), fps=fps)
    return out
