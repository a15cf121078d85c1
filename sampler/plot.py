"""The Vm map: Vm over two chosen parameters with the MCMC buffer on top (Won & Lee 2019, Fig. 6).

The learner writes it into the run directory from the sampler's state (`SamplerClient.get_state`),
so it works wherever the sampler actor runs:

    plot_state(client.get_state(), space, run_dir / "sampler_vm.png", params=("leg", "arm"))
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import matplotlib

matplotlib.use("Agg")  # files only: no display on training machines
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from common.params import ParamSpace  # noqa: E402
from sampler.marginal_value import MarginalValue  # noqa: E402


def map_axes(space: ParamSpace, params: Sequence[str] | None, flag: str = "--sampler.plot-params") -> tuple[int, int]:
    """Indices of a map's two parameters (default: the first two of `space`); ValueError naming
    `flag` and its value unless they are two different names of `space`. The one check of both
    the Vm map's `--sampler.plot-params` (made when a run starts) and evaluation's `--map-params`."""
    names = tuple(params) if params else space.names[:2]
    if len(names) != 2 or len(set(names)) != 2 or any(n not in space.names for n in names):
        raise ValueError(f"{flag} {list(names)}: choose two different names from {list(space.names)}")
    return space.names.index(names[0]), space.names.index(names[1])


def has_map(space: ParamSpace, params: Sequence[str] | None = None) -> bool:
    """Whether the map over `params` (default the first two; a 1-D space its one) has width along
    every axis: a fixed body, such as the executor's humanoid or a `-fixedshape` run, has none."""
    axes = (0,) if space.dim == 1 else map_axes(space, params)
    return all(space.high[k] > space.low[k] for k in axes)


def plot_marginal_value(vm: MarginalValue, space: ParamSpace, buffer: np.ndarray | None, path: str | Path,
                        params: Sequence[str] | None = None, resolution: int = 64, title: str = "") -> Path | None:
    """Write a PNG of Vm over `params` (two names; default the first two), the other parameters
    held at the buffer's mean (or the space's default without a buffer), with the buffer's
    `[n, d]` points overlaid. A 1-D space gets Vm as a curve over the buffer's histogram.
    Returns the path, or None (nothing written) when an axis has no width: a fixed body, such as
    the executor's humanoid or a `-fixedshape` run, has no map to draw."""
    if not has_map(space, params):
        return None
    if space.dim == 1:
        return _plot_1d(vm, space, buffer, Path(path), resolution, title)
    i, j = map_axes(space, params)
    fixed = buffer.mean(axis=0) if buffer is not None and len(buffer) else space.default_array
    gi = np.linspace(space.low[i], space.high[i], resolution)
    gj = np.linspace(space.low[j], space.high[j], resolution)
    mesh_i, mesh_j = np.meshgrid(gi, gj)
    grid = np.tile(fixed, (mesh_i.size, 1))
    grid[:, i], grid[:, j] = mesh_i.ravel(), mesh_j.ravel()
    values = vm(grid).reshape(mesh_i.shape)

    fig, ax = plt.subplots(figsize=(5.5, 4.5), dpi=120)
    mesh = ax.pcolormesh(mesh_i, mesh_j, values, shading="auto", cmap="viridis")
    fig.colorbar(mesh, ax=ax, label="Vm (expected return)")
    if buffer is not None and len(buffer):
        ax.scatter(buffer[:, i], buffer[:, j], s=4, c="white", edgecolors="black", linewidths=0.2,
                   alpha=0.7, label=f"buffer ({len(buffer)})")
        ax.legend(loc="upper right", fontsize=7, framealpha=0.6)
    ax.set_xlabel(space.names[i])
    ax.set_ylabel(space.names[j])
    ax.set_xlim(space.low[i], space.high[i])
    ax.set_ylim(space.low[j], space.high[j])
    ax.set_title(title or "marginal value Vm and MCMC buffer", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def _plot_1d(vm: MarginalValue, space: ParamSpace, buffer: np.ndarray | None, path: Path,
             resolution: int, title: str) -> Path:
    grid = np.linspace(space.low[0], space.high[0], resolution)[:, None]
    fig, ax = plt.subplots(figsize=(5.5, 4.0), dpi=120)
    ax.plot(grid[:, 0], vm(grid), color="tab:blue")
    ax.set_xlabel(space.names[0])
    ax.set_ylabel("Vm (expected return)", color="tab:blue")
    if buffer is not None and len(buffer):
        twin = ax.twinx()
        twin.hist(buffer[:, 0], bins=30, range=(space.low[0], space.high[0]), color="gray", alpha=0.4)
        twin.set_ylabel(f"buffer count ({len(buffer)})")
    ax.set_title(title or "marginal value Vm and MCMC buffer", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_state(state: dict[str, Any], space: ParamSpace, path: str | Path,
               params: Sequence[str] | None = None, resolution: int = 64) -> Path | None:
    """The same PNG from a sampler state (`SamplerClient.get_state()` or `ShapeSampler.state_dict()`);
    None when an axis has no width."""
    if not has_map(space, params):
        return None
    meta, arrays = state["meta"], state["arrays"]
    vm = MarginalValue(space.low_array, space.high_array, tuple(meta["vm"]["hidden"]))
    vm.load_state(meta["vm"], {k[3:]: np.asarray(v) for k, v in arrays.items() if k.startswith("vm/")})
    buffer = np.asarray(arrays["buffer"], dtype=np.float64).reshape(-1, space.dim)
    title = (f"Vm and buffer: iteration {meta['last_tick']}, refill {meta['generation']}, "
             f"Vbar {meta['vm']['vbar']:.3g}")
    return plot_marginal_value(vm, space, buffer, path, params, resolution, title)
