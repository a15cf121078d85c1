"""Evaluation building blocks: load a checkpoint into a policy, draw the evaluation shapes, run
deterministic episodes (Won & Lee 2019 protocol: random shapes from a fixed seed, 30 s
episodes; task achievement = cumulative task reward R_task, fall-down = episodes that end in a
fall). No plotting and no CLI here (evaluate.py, morph_demo.py, ablation.py use it).
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from common.motion.check import body_clearance, root_bob
from common.policy import GaussianPolicy
from common.tasks.base import TaskConfig
from common.tasks.registry import make_env
from learner import checkpoint
from learner.config import RunConfig
from learner.evaluation.shape.swim_metrics import SwimTracker, summarize_swim


@dataclass(frozen=True)
class Loaded:
    """A checkpoint ready to run: its resolved run config, the raw state and where it came from."""

    cfg: RunConfig
    state: dict[str, Any]
    path: Path

    @property
    def name(self) -> str:
        return self.cfg.name


def resolve(path: str | Path) -> Path:
    """A checkpoint directory (with state.pt), a state.pt file, a run directory (its newest
    `ckpt/<it>/`) or a shipped `learner/pretrained/<name>` -> the state.pt file."""
    p = Path(path)
    if p.is_file():
        return p
    if (p / checkpoint.FILE).is_file():
        return p / checkpoint.FILE
    found = checkpoint.list_checkpoints(p / "ckpt")
    if found:
        return found[-1] / checkpoint.FILE
    raise SystemExit(f"--checkpoint {path}: no state.pt there, nor a run directory with ckpt/<iteration>/state.pt")


def load(path: str | Path) -> Loaded:
    file = resolve(path)
    try:
        state = checkpoint.load(file)
    except checkpoint.CheckpointError as exc:
        raise SystemExit(str(exc)) from None
    if "config" not in state or "policy" not in state:
        raise SystemExit(f"{file} holds no 'config'/'policy': not a morphmimic training checkpoint")
    try:
        cfg = RunConfig.from_json(str(state["config"]))
        if cfg.task.name == "executor":  # its named clips must play on the humanoid
            from common.tasks.executor.env import labelled_clips

            labelled_clips(cfg.task)
    except ValueError as exc:
        raise SystemExit(f"{file}: its saved configuration is refused: {exc}") from None
    return Loaded(cfg, state, file)


def check_box_scale(box_scale: float) -> float:
    """`box_scale` if it is in (0, 1], else ValueError naming it and the range."""
    if not 0.0 < box_scale <= 1.0:
        raise ValueError(f"box scale {box_scale:g} must be in (0, 1] (1: the whole box, the paper's protocol)")
    return box_scale


def eval_task(cfg: TaskConfig, episode_s: float, box_scale: float = 1.0) -> TaskConfig:
    """The task as evaluated: every shape of the parameterization (even for a checkpoint trained
    on one shape or a shrunken box), a fixed start at phase 0, the given horizon. `box_scale` < 1
    evaluates on the box shrunk toward the base shape instead (a curriculum's progress; not the
    paper's protocol)."""
    check_box_scale(box_scale)
    return dataclasses.replace(cfg, episode_s=episode_s,
                               body=dataclasses.replace(cfg.body, vary_shape=True, shape_box_scale=box_scale),
                               imitate=dataclasses.replace(cfg.imitate, random_start_phase=False))


def make_policy(loaded: Loaded, obs_dim: int, act_dim: int) -> GaussianPolicy:
    policy = GaussianPolicy(obs_dim, act_dim, loaded.cfg.policy)
    try:
        policy.load_state_dict(loaded.state["policy"])
    except (RuntimeError, TypeError, AttributeError) as exc:  # wrong shapes or keys; not a state dict at all
        raise SystemExit(f"{loaded.path}: the policy does not fit task {loaded.cfg.task.name!r} as this code builds it "
                         f"(obs {obs_dim}, act {act_dim}): {exc}") from None
    policy.eval()
    return policy


class ZeroPolicy:
    """Acts with zero actions, the baseline a trained policy is measured against: for a PD task
    the character's PD on the reference itself (a zero deviation from the target pose), for a
    torque task no torque."""

    def __init__(self, act_dim: int) -> None:
        self.act_dim = int(act_dim)

    def act(self, obs_raw: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, np.ndarray]:
        n = len(obs_raw)
        return np.zeros((n, self.act_dim), np.float32), np.zeros(n, np.float32)


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
    import hashlib

    from common.characters.character import build_base

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
    loaded = load(state_file)
    cfg = loaded.cfg.task
    task = eval_task(dataclasses.replace(cfg, imitate=dataclasses.replace(cfg.imitate, **imitate_overrides)),
                     episode_s, box_scale)
    env = make_env(task, seed=0)
    _WORKER.update(env=env, policy=make_policy(loaded, env.obs_dim, env.act_dim))


def _work(job: tuple[int, np.ndarray, int]) -> dict[str, Any]:
    i, params, seed = job
    out = run_episode(_WORKER["env"], _WORKER["policy"], params, seed)
    return {"index": i, "params": [float(x) for x in params], **out}


def evaluate(loaded: Loaded, shapes: np.ndarray, episode_s: float, seed: int, workers: int = 1,
             progress: Callable[[int, int], None] | None = None, imitate_overrides: dict | None = None,
             box_scale: float = 1.0) -> list[dict]:
    """Run one episode per row of `shapes` (inside the box `eval_task(..., box_scale)` accepts);
    results in row order. `workers` > 1 uses processes. `imitate_overrides`: fields of the
    task's `imitate` section to change (`{"shin_contact_is_fall": True}`: the paper's fall rule)."""
    jobs = [(i, shapes[i], seed + i) for i in range(len(shapes))]
    init = (str(loaded.path), dict(imitate_overrides or {}), episode_s, box_scale)
    return run_jobs(_init_worker, init, _work, jobs, workers, progress)


def run_jobs(init: Callable, init_args: tuple, work: Callable[[Any], dict], jobs: list, workers: int,
             progress: Callable[[int, int], None] | None = None) -> list[dict]:
    """`work(job)` for every job, in this process (`workers` <= 1) or in a pool of forked
    processes each set up once by `init(*init_args)`; results (dicts with an "index") sorted by
    their index. `progress(done, total)` is called after each job."""
    results: list[dict] = []
    if workers <= 1:
        init(*init_args)
        for job in jobs:
            results.append(work(job))
            if progress:
                progress(len(results), len(jobs))
    else:
        ctx = multiprocessing.get_context("fork")
        with ctx.Pool(min(workers, len(jobs)), initializer=init, initargs=init_args) as pool:
            for res in pool.imap_unordered(work, jobs):
                results.append(res)
                if progress:
                    progress(len(results), len(jobs))
    return sorted(results, key=lambda r: r["index"])


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


EXECUTOR_ONLY_OPTIONS = ("--clips", "--starts", "--zero-action", "--set")
"""Options only the motion executor's evaluation commands take."""


def names_executor(argv: list[str], checkpoint_option: str) -> bool:
    """Whether an evaluation command's arguments are for a motion executor: they use an
    executor-only option, or the (first) checkpoint given by `checkpoint_option` is one. A
    checkpoint that cannot be loaded answers False (the shape command then reports it)."""
    if any(a.split("=", 1)[0] in EXECUTOR_ONLY_OPTIONS for a in argv):
        return True
    import argparse

    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument(checkpoint_option, nargs="+", default=[])
    known, _ = pre.parse_known_args(argv)
    paths = getattr(known, checkpoint_option.lstrip("-").replace("-", "_"))
    if not paths:
        return False
    try:
        return load(paths[0]).cfg.task.name == "executor"
    except SystemExit:
        return False


def write_ablation(out: Path, text: str, arms: list[dict[str, Any]]) -> None:
    """An ablation command's outputs: the markdown table `out/ablation.md`, one JSON entry per
    arm in `out/ablation.json`, and the table printed."""
    (out / "ablation.md").write_text(text)
    (out / "ablation.json").write_text(json.dumps(arms, indent=1) + "\n")
    print(text)
