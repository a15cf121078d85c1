"""The shape controllers' evaluation (Won & Lee 2019 protocol: random shapes from a fixed seed,
30 s episodes; task achievement = cumulative task reward R_task, fall-down = episodes that end in
a fall): draw the shapes, run deterministic episodes, summarize them. No plotting and no CLI
here (`shape/evaluate.py`, `shape/morph_demo.py`, `shape/ablation.py` use it).
"""

from __future__ import annotations

import dataclasses
import hashlib
from typing import Any, Callable

import numpy as np
import torch

from common.characters.character import build_base
from common.motion.check import body_clearance, root_bob
from common.policy import GaussianPolicy
from common.tasks.registry import make_env
from learner import checkpoint
from learner.evaluation.harness import eval_task, run_jobs
from learner.evaluation.shape.swim_metrics import SwimTracker, summarize_swim


def eval_shapes(space, n: int, seed: int) -> np.ndarray:
    """`[n, dim]` uniform draws over the task's full parameter box from a fixed seed."""
    return space.uniform(np.random.default_rng(seed), n)


def extremeness(space, params: np.ndarray, n_shape: int | None = None) -> np.ndarray:
    """`[n]` how far each shape is from the base character: the L2 norm of the shape parameters
    mapped so that the base (default) value is 0 and each end of the box is +-1, one scale per
    side, since the box is lopsided around the base (leg length 0.5-2.0 around 1.0). 0 = the base
    shape, the shape a box shrinks toward. Won & Lee 2019 report that adaptive sampling makes
    extreme shapes fall far less (METHOD.md A, results)."""
    params = np.atleast_2d(params)
    k = n_shape or params.shape[1]
    lo, hi, base = space.low_array[:k], space.high_array[:k], space.default_array[:k]
    d = params[:, :k] - base
    side = np.where(d > 0, hi - base, base - lo)
    return np.linalg.norm(np.where(side > 0, d / np.where(side > 0, side, 1.0), 0.0), axis=1)


def run_episode(env, policy: GaussianPolicy, params: np.ndarray, seed: int,
                on_step: Callable[[Any, int], None] | None = None) -> dict[str, Any]:
    """One deterministic (mean action) episode; `on_step(env, k)` is called after each step.
    A walker's result also has its reference's root bob (`reference_root_bob`), a swimmer's its
    speed, heading and upright figures (`swim_metrics.SwimTracker`)."""
    obs, _ = env.reset(seed, params)
    bob = reference_root_bob(env)
    swim = SwimTracker() if getattr(getattr(env, "character", None), "is_swimmer", False) else None
    ret = task = imit = 0.0
    fell = diverged = fell_paper = False
    fall_bodies: list[str] = []
    k = 0
    while True:
        action, _ = policy.act(obs[None], deterministic=True)
        obs, r, term, trunc, info = env.step(action[0])
        k += 1
        ret += r
        task += float(info.get("task_reward", 0.0))
        imit += float(info.get("imitation_reward", 0.0))
        fell_paper = fell_paper or bool(info.get("fell_paper_rule", False))
        if swim is not None:
            swim(env, k)
        if on_step is not None:
            on_step(env, k)
        if term or trunc:
            fell = bool(term and info.get("fell", True))
            diverged = bool(info.get("diverged"))
            fall_bodies = list(info.get("fall_bodies", [])) if fell else []
            break
    return {"return": ret, "task_reward": task, "imitation_reward": imit, "steps": k, "fell": fell,
            "diverged": diverged, "seconds": k / env.cfg.control_hz, "fall_bodies": fall_bodies,
            "fell_paper_rule": fell_paper or fell or diverged, **bob, **(swim.result() if swim is not None else {})}


def body_digest(preset: str) -> str:
    """12 hex digits of SHA-1 over a character preset's base body as MJCF (before any shape):
    results measured on another body (a character's geometry changed between commits, as the
    quadruped's shank did on 2026-12-04) are not reused by `morphmimic ablation`."""
    return hashlib.sha1(build_base(preset).spec.to_xml().encode()).hexdigest()[:12]


def reference_root_bob(env) -> dict[str, Any]:
    """The retargeted reference on the env's current shape, for characters with feet ({} else):
    its root-height range and largest step between frames (m, `common.motion.check.root_bob`),
    and how close it brings a body whose floor contact is a fall under the task's rule to the
    floor (`ref_clearance_m`, `ref_clearance_body`; `common.motion.check.body_clearance`)."""
    motion, character = getattr(env, "motion", None), getattr(env, "character", None)
    if motion is None or not getattr(character, "foot_geoms", ()):
        return {}
    span, step = root_bob(motion.qpos_frames)
    out: dict[str, Any] = {"ref_root_range_m": span, "ref_root_step_m": step}
    allowed = getattr(env, "allowed_contact", None)
    if allowed is not None:
        clearance, body = body_clearance(env.model, motion.qpos_frames, np.flatnonzero(~allowed))
        if np.isfinite(clearance):
            out.update(ref_clearance_m=clearance, ref_clearance_body=body)
    return out


ROOT_RANGE_BINS_M = (0.03, 0.06, 0.10)
"""Edges of the summary's fall-down table by the reference's root range (m)."""

CLEARANCE_BINS_M = (0.005, 0.02)
"""Edges (besides 0) of the summary's fall-down table by the reference's clearance of the bodies
that may not touch the floor (m)."""


def _falls_by(results: list[dict], field: str, edges: tuple[float, ...], key: str) -> list[dict[str, Any]]:
    """Fall-down % per bin of `field` between `edges` (m, -inf and inf added at the ends), for
    results that carry it; each row labels its bin in cm under `key`."""
    rows = [r for r in results if field in r]
    if not rows:
        return []
    x = np.array([r[field] for r in rows])
    fell = np.array([r["fell"] or r["diverged"] for r in rows], dtype=bool)
    bounds = (-np.inf, *edges, np.inf)
    out = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        inside = (x >= lo) & (x < hi)
        if not np.isfinite(lo) and not inside.any():
            continue  # the open lower bin only where something falls in it
        label = (f"under {100 * hi:g} cm" if not np.isfinite(lo) else
                 f"{100 * lo:g}-{100 * hi:g} cm" if np.isfinite(hi) else f"over {100 * lo:g} cm")
        out.append({key: label, "shapes": int(inside.sum()),
                    "fall_down_pct": float(100.0 * fell[inside].mean()) if inside.any() else None})
    return out


def falls_by_root_range(results: list[dict]) -> list[dict[str, Any]]:
    """Fall-down % per bin of the reference's root-height range (`ROOT_RANGE_BINS_M`), for
    results that carry it: where a retargeting moves the root where the clip does not, the
    shapes with the largest range fall most (the quadruped under "contact_set")."""
    return _falls_by(results, "ref_root_range_m", (0.0, *ROOT_RANGE_BINS_M), "root_range")


def falls_by_clearance(results: list[dict]) -> list[dict[str, Any]]:
    """Fall-down % per bin of how close the reference brings a body that may not touch the floor
    to it (`ref_clearance_m`; under 0: the reference itself puts it into the floor)."""
    return _falls_by(results, "ref_clearance_m", (0.0, *CLEARANCE_BINS_M), "clearance")


_WORKER: dict[str, Any] = {}


def _init_worker(state_file: str, imitate_overrides: dict, episode_s: float, box_scale: float) -> None:
    torch.set_num_threads(1)
    loaded = checkpoint.load_trained(state_file)
    cfg = loaded.cfg.task
    task = eval_task(dataclasses.replace(cfg, imitate=dataclasses.replace(cfg.imitate, **imitate_overrides)),
                     episode_s, box_scale)
    env = make_env(task, seed=0)
    _WORKER.update(env=env, policy=checkpoint.make_policy(loaded, env.obs_dim, env.act_dim))


def _work(job: tuple[int, np.ndarray, int]) -> dict[str, Any]:
    i, params, seed = job
    out = run_episode(_WORKER["env"], _WORKER["policy"], params, seed)
    return {"index": i, "params": [float(x) for x in params], **out}


def evaluate(loaded: checkpoint.Loaded, shapes: np.ndarray, episode_s: float, seed: int, workers: int = 1,
             progress: Callable[[int, int], None] | None = None, imitate_overrides: dict | None = None,
             box_scale: float = 1.0) -> list[dict]:
    """Run one episode per row of `shapes` (inside the box `eval_task(..., box_scale)` accepts);
    results in row order. `workers` > 1 uses processes. `imitate_overrides`: fields of the
    task's `imitate` section to change (`{"shin_contact_is_fall": True}`: the paper's fall rule)."""
    jobs = [(i, shapes[i], seed + i) for i in range(len(shapes))]
    init = (str(loaded.path), dict(imitate_overrides or {}), episode_s, box_scale)
    return run_jobs(_init_worker, init, _work, jobs, workers, progress)


def summarize(results: list[dict], space, n_shape: int) -> dict[str, Any]:
    """Task achievement (mean cumulative task reward), fall-down %, mean return and the
    fall-down % on the most extreme 10% of shapes (by `extremeness`). An episode the simulator
    diverged in ended before its length too, so it counts as a fall (and in `diverged`).
    `falls_by_body`: how many falls each body's floor contact ended (a fall may name several)."""
    params = np.array([r["params"] for r in results])
    fell = np.array([r["fell"] or r["diverged"] for r in results], dtype=bool)
    ext = extremeness(space, params, n_shape)
    top = np.argsort(ext)[-max(1, len(results) // 10):]
    by_body: dict[str, int] = {}
    for r in results:
        for name in r.get("fall_bodies", []):
            by_body[name] = by_body.get(name, 0) + 1
    return {
        "shapes": len(results),
        "task_achievement": float(np.mean([r["task_reward"] for r in results])),
        "fall_down_pct": float(100.0 * fell.mean()),
        "fall_down_pct_paper_rule": float(100.0 * np.mean([r.get("fell_paper_rule", f) for r, f in zip(results, fell)])),
        "mean_return": float(np.mean([r["return"] for r in results])),
        "mean_seconds": float(np.mean([r["seconds"] for r in results])),
        "diverged": int(sum(r["diverged"] for r in results)),
        "fall_down_pct_extreme10": float(100.0 * fell[top].mean()),
        "falls_by_body": dict(sorted(by_body.items(), key=lambda kv: (-kv[1], kv[0]))),
        "falls_by_ref_root_range": falls_by_root_range(results),
        "falls_by_ref_clearance": falls_by_clearance(results),
        **summarize_swim(results),
    }
