"""The Vm map: Vm over two chosen parameters with the MCMC buffer on top (Won & Lee 2019, Fig. 6).

The learner writes it into the run directory from the sampler's state (`SamplerClient.get_state`),
so it works wherever the sampler actor runs:

    plot_state(client.get_state(), space, run_dir / "sampler_vm.png", params=("leg", "arm"))

A sampler over (shape, class) (`--sampler.shape-by-class`) gets the class map instead: one panel
per motion class, Vm(., c) over the two parameters with the others at their base values, that
class's buffer on top, one colour scale for all panels so the hard (shape, class) pairs stand out
(`plot_class_map`). From a saved sampler state, without the run:

    python -m sampler.plot <run>/sampler vm_classes.png --params height thickness
"""

from __future__ import annotations

from pathlib import Path
import argparse
import math
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
    mesh_i, mesh_j, values = _grid_values(lambda g: vm(g), space, i, j, fixed, resolution)

    fig, ax = plt.subplots(figsize=(5.5, 4.5), dpi=120)
    mesh = _panel(ax, space, i, j, mesh_i, mesh_j, values, buffer)
    fig.colorbar(mesh, ax=ax, label="Vm (expected return)")
    ax.set_title(title or "marginal value Vm and MCMC buffer", fontsize=9)
    fig.tight_layout()
    return _save(fig, path)


def _grid_values(fn, space: ParamSpace, i: int, j: int, fixed: np.ndarray,
                 resolution: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Meshes of parameters i and j over the box and `fn` on them, the other parameters at `fixed`."""
    gi = np.linspace(space.low[i], space.high[i], resolution)
    gj = np.linspace(space.low[j], space.high[j], resolution)
    mesh_i, mesh_j = np.meshgrid(gi, gj)
    grid = np.tile(fixed, (mesh_i.size, 1))
    grid[:, i], grid[:, j] = mesh_i.ravel(), mesh_j.ravel()
    return mesh_i, mesh_j, np.asarray(fn(grid)).reshape(mesh_i.shape)


def _panel(ax, space: ParamSpace, i: int, j: int, mesh_i: np.ndarray, mesh_j: np.ndarray, values: np.ndarray,
           buffer: np.ndarray | None, vmin: float | None = None, vmax: float | None = None):
    """One Vm map on `ax` with the buffer's points on top; returns the mesh (for a colour bar)."""
    mesh = ax.pcolormesh(mesh_i, mesh_j, values, shading="auto", cmap="viridis", vmin=vmin, vmax=vmax)
    if buffer is not None and len(buffer):
        ax.scatter(buffer[:, i], buffer[:, j], s=4, c="white", edgecolors="black", linewidths=0.2,
                   alpha=0.7, label=f"buffer ({len(buffer)})")
        ax.legend(loc="upper right", fontsize=7, framealpha=0.6)
    ax.set_xlabel(space.names[i])
    ax.set_ylabel(space.names[j])
    ax.set_xlim(space.low[i], space.high[i])
    ax.set_ylim(space.low[j], space.high[j])
    return mesh


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_class_map(vm: MarginalValue, space: ParamSpace, buffers: Sequence[np.ndarray | None], path: str | Path,
                   params: Sequence[str] | None = None, resolution: int = 48, title: str = "",
                   vbar: Sequence[float] | None = None) -> Path | None:
    """Write a PNG of Vm(., c) over `params` (two names; default the first two) for each class
    of `vm` (a Vm over classes), one panel per class, the other parameters at the space's base
    values (`default`), that class's buffer (`buffers[c]`, `[n, d]` or None) on top and one colour
    scale for every panel; `vbar`: each class's Vbar_c, shown in its title. A 1-D space gets one
    curve per class. None (nothing written) when an axis has no width."""
    if not vm.n_classes:
        raise ValueError("plot_class_map needs a Vm over classes (--sampler.shape-by-class)")
    if not has_map(space, params):
        return None
    names = vm.classes
    if space.dim == 1:
        grid = np.linspace(space.low[0], space.high[0], resolution)[:, None]
        fig, ax = plt.subplots(figsize=(6.5, 4.0), dpi=120)
        for c, name in enumerate(names):
            ax.plot(grid[:, 0], vm(grid, c), label=name)
        ax.set_xlabel(space.names[0])
        ax.set_ylabel("Vm (expected return)")
        ax.legend(fontsize=6, ncol=2)
        ax.set_title(title or "marginal value Vm per class", fontsize=9)
        fig.tight_layout()
        return _save(fig, path)
    i, j = map_axes(space, params)
    maps = [_grid_values(lambda g, c=c: vm(g, c), space, i, j, space.default_array, resolution) for c in range(len(names))]
    lo = min(float(v.min()) for _, _, v in maps)
    hi = max(float(v.max()) for _, _, v in maps)
    cols = min(len(names), max(1, math.ceil(math.sqrt(len(names)))))
    rows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols + 1.0, 2.8 * rows + 0.6), dpi=100, squeeze=False)
    mesh = None
    for c, name in enumerate(names):
        ax = axes[c // cols][c % cols]
        mesh = _panel(ax, space, i, j, *maps[c], buffers[c] if c < len(buffers) else None, lo, hi)
        ax.set_title(name + (f"  Vbar {vbar[c]:.3g}" if vbar is not None else ""), fontsize=7)
        ax.tick_params(labelsize=6)
        ax.xaxis.label.set_size(7)
        ax.yaxis.label.set_size(7)
    for c in range(len(names), rows * cols):
        axes[c // cols][c % cols].set_visible(False)
    fig.colorbar(mesh, ax=axes.ravel().tolist(), label="Vm (expected return)")
    fig.suptitle(title or "marginal value Vm per motion class", fontsize=9)
    return _save(fig, path)


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
    classes = [str(c) for c in meta["vm"].get("classes", [])]
    vm = MarginalValue(space.low_array, space.high_array, tuple(meta["vm"]["hidden"]), classes=classes)
    vm.load_state(meta["vm"], {k[3:]: np.asarray(v) for k, v in arrays.items() if k.startswith("vm/")})
    buffer = np.asarray(arrays["buffer"], dtype=np.float64).reshape(-1, space.dim)
    title = (f"Vm and buffer: iteration {meta['last_tick']}, refill {meta['generation']}, "
             f"Vbar {meta['vm']['vbar']:.3g}")
    if classes:  # the sampler's buffers, one per class, side by side (`ShapeSampler`)
        per = len(buffer) // len(classes)
        buffers = [buffer[c * per:(c + 1) * per] for c in range(len(classes))]
        return plot_class_map(vm, space, buffers, path, params, resolution, title, vbar=vm.vbar_c)
    return plot_marginal_value(vm, space, buffer, path, params, resolution, title)


def space_of_state(state: dict[str, Any]) -> ParamSpace:
    """The parameter box a sampler state was saved over (its names and Vm's box; the base values
    are the box's centres: a state does not keep the task's defaults)."""
    meta = state["meta"]
    return ParamSpace(names=tuple(meta["names"]), low=tuple(meta["vm"]["low"]), high=tuple(meta["vm"]["high"]))


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m sampler.plot STATE OUT.png [--params A B]`: the Vm map (or the class map) of a
    saved sampler state (a state directory or its `sampler-state.npz`)."""
    from sampler import state_file  # lazy: only for the command

    ap = argparse.ArgumentParser(prog="python -m sampler.plot", description=main.__doc__)
    ap.add_argument("state", help="the sampler's state directory (<run>/sampler) or its sampler-state.npz")
    ap.add_argument("out", help="PNG to write")
    ap.add_argument("--params", nargs=2, default=None, metavar=("X", "Y"), help="the map's two parameters")
    args = ap.parse_args(argv)
    where = Path(args.state)
    state = state_file.load(where.parent if where.name == state_file.FILE else where)
    if state is None:
        ap.error(f"no readable sampler state in {where}")
    space = space_of_state(state)
    out = plot_state(state, space, args.out, params=args.params)
    print(out if out is not None else "no map: an axis of the box has no width")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
