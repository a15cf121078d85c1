"""Pictures for the evaluation: the measured-return map over two shape parameters, the
marginal value map from the checkpoint's sampler state (Won & Lee 2019, Fig. 6), and PNG
strips / GIFs of episodes (MuJoCo's offscreen renderer; common.offscreen_gl picks EGL or OSMesa headless).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from common.offscreen_gl import use_offscreen_context  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from common.params import ParamSpace  # noqa: E402


def axes_of(space: ParamSpace, names: Sequence[str] | None) -> tuple[int, int]:
    """Indices of the two map parameters (default: the first two of the space); SystemExit naming
    `--map-params` unless they are two different names of it (`sampler.plot.map_axes`)."""
    from sampler.plot import map_axes  # lazy: heavy (torch, through sampler), only for a map's axes

    try:
        return map_axes(space, names, flag="--map-params")
    except ValueError as exc:
        raise SystemExit(str(exc)) from None


def binned_grid(space: ParamSpace, params: np.ndarray, values: np.ndarray, ij: tuple[int, int], bins: int) -> np.ndarray:
    """`[bins, bins]` mean of `values` per cell of the (i, j) parameter grid (NaN where empty):
    the return marginalized over every other parameter, as the random shapes sample them."""
    i, j = ij
    edges_i = np.linspace(space.low[i], space.high[i], bins + 1)
    edges_j = np.linspace(space.low[j], space.high[j], bins + 1)
    bi = np.clip(np.digitize(params[:, i], edges_i) - 1, 0, bins - 1)
    bj = np.clip(np.digitize(params[:, j], edges_j) - 1, 0, bins - 1)
    total = np.zeros((bins, bins))
    count = np.zeros((bins, bins))
    np.add.at(total, (bj, bi), values)
    np.add.at(count, (bj, bi), 1)
    with np.errstate(invalid="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def uniformity(grid: np.ndarray) -> float:
    """min / mean over the filled cells of a return map (1 = perfectly uniform)."""
    filled = grid[np.isfinite(grid)]
    if filled.size == 0 or filled.mean() == 0:
        return float("nan")
    return float(filled.min() / filled.mean())


def plot_return_map(space: ParamSpace, params: np.ndarray, values: np.ndarray, fell: np.ndarray, names, path: Path,
                    bins: int = 6, title: str = "") -> np.ndarray:
    """PNG of the binned measured return over two parameters with every shape on top (x = fell).
    Returns the grid."""
    i, j = axes_of(space, names)
    grid = binned_grid(space, params, values, (i, j), bins)
    fig, ax = plt.subplots(figsize=(5.5, 4.5), dpi=120)
    mesh = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis",
                     extent=(space.low[i], space.high[i], space.low[j], space.high[j]))
    fig.colorbar(mesh, ax=ax, label="mean return per cell")
    ok = ~fell
    ax.scatter(params[ok, i], params[ok, j], s=6, c="white", edgecolors="black", linewidths=0.2, label="stayed up")
    ax.scatter(params[fell, i], params[fell, j], s=12, c="red", marker="x", linewidths=0.8, label="fell")
    ax.legend(loc="upper right", fontsize=7, framealpha=0.6)
    ax.set_xlabel(space.names[i])
    ax.set_ylabel(space.names[j])
    ax.set_title(title or f"measured return (min/mean {uniformity(grid):.2f})", fontsize=9)
    save_figure(fig, path)
    return grid


def save_figure(fig, path: Path) -> Path:
    """Lay out, write (making the folder) and close a matplotlib figure; returns `path`."""
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def vm_of(sampler_state: dict[str, Any], train_space: ParamSpace, params: np.ndarray) -> np.ndarray | None:
    """Vm at `[n, d]` parameters from a checkpoint's sampler state (None if it has none)."""
    from sampler.marginal_value import MarginalValue  # lazy: heavy (torch), only with a sampler state

    if not sampler_state:
        return None
    meta, arrays = sampler_state["meta"], sampler_state["arrays"]
    vm = MarginalValue(train_space.low_array, train_space.high_array, tuple(meta["vm"]["hidden"]))
    vm.load_state(meta["vm"], {k[3:]: np.asarray(v) for k, v in arrays.items() if k.startswith("vm/")})
    return vm(np.clip(params, train_space.low_array, train_space.high_array))


def plot_vm_map(sampler_state: dict[str, Any], train_space: ParamSpace, names, path: Path) -> Path | None:
    """The sampler's own Vm map PNG (sampler.plot.plot_state); None when the training space
    has no width along a map axis (a fixed-shape run)."""
    from sampler.plot import plot_state  # lazy: heavy (torch, through sampler), only with a sampler state

    i, j = axes_of(train_space, names)
    if not sampler_state:
        return None
    return plot_state(sampler_state, train_space, path, params=[train_space.names[i], train_space.names[j]])


class FollowRenderer:
    """Offscreen frames of an environment with a camera that follows its root; the model may
    change under it (a morph), the renderer is rebuilt then."""

    def __init__(self, width: int = 320, height: int = 320):
        self.width, self.height = width, height
        self._renderer = None
        self._model = None

    def render(self, env, root_body: int, swimmer: bool = False, distance_m: float | None = None,
               elevation_deg: float | None = None) -> np.ndarray:
        """`[height, width, 3]` uint8 of `env.model` / `env.data` now; `distance_m` and
        `elevation_deg` (a task's own view, as the reach arm's) replace the characters' camera."""
        if self._model is not env.model:
            self.close()
            self._model = env.model
            use_offscreen_context()
            self._renderer = mujoco.Renderer(env.model, height=self.height, width=self.width)
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = env.data.subtree_com[root_body]
        cam.distance = distance_m or (3.0 if not swimmer else 2.5)
        cam.azimuth, cam.elevation = 120.0, -(elevation_deg or (30.0 if swimmer else 12.0))
        self._renderer.update_scene(env.data, camera=cam)
        return self._renderer.render().copy()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class Recorder(FollowRenderer):
    """Collects frames of an episode every `every` control steps (`FollowRenderer`)."""

    def __init__(self, every: int, width: int = 320, height: int = 320):
        super().__init__(width, height)
        self.every = every
        self.frames: list[np.ndarray] = []

    def __call__(self, env, k: int) -> None:
        if k % self.every:
            return
        self.frames.append(self.render(env, env.root_body, env.character.is_swimmer))

    def write_strip(self, path: Path, n: int = 8) -> Path | None:
        """A PNG of `n` frames side by side, evenly spaced over the episode."""
        import imageio.v3 as iio  # lazy: heavy (imageio), only when writing frames

        if not self.frames:
            return None
        idx = np.linspace(0, len(self.frames) - 1, min(n, len(self.frames))).round().astype(int)
        path.parent.mkdir(parents=True, exist_ok=True)
        iio.imwrite(str(path), np.concatenate([self.frames[i] for i in idx], axis=1))
        return path

    def write_gif(self, path: Path, fps: float) -> Path | None:
        import imageio.v2 as imageio  # lazy: heavy (imageio), only when writing frames

        if not self.frames:
            return None
        path.parent.mkdir(parents=True, exist_ok=True)
        imageio.mimsave(str(path), self.frames, duration=1.0 / fps, loop=0)
        return path
