"""The reach task's evaluation episodes and figures: the policy (mean action) on random targets
from a fixed seed, every target's episode stepped in lockstep (one batched policy call per
control step), and what an arm is judged by: how far the fingertip ends from the target, how
many targets it ends within `radius_m` of (success), how many it came within that distance of
at some step (reached) and how soon, and the reward per step. Nothing here falls: a fall-down
rate would say nothing about an arm. No plotting and no CLI (`reach/evaluate.py`, `reach/curve.py`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from common.tasks.registry import make_env, task_space
from learner import checkpoint
from learner.evaluation.harness import ZeroPolicy

SUCCESS_RADIUS_M = 0.02
"""Success: the fingertip ends within 2 cm of the target (the reward's bell,
`exp(-d / 0.03)`, is 0.51 there)."""
TARGETS = 100
SEED = 2019


def eval_targets(loaded: checkpoint.Loaded, n: int, seed: int) -> np.ndarray:
    """`[n, 2]` targets (polar angle, radius) drawn uniformly over the task's box from a fixed
    seed: every checkpoint of a run sees the same ones."""
    return task_space(loaded.cfg.task).uniform(np.random.default_rng(seed), n)


def run(loaded: checkpoint.Loaded, targets: np.ndarray, episode_s: float, seed: int, radius_m: float,
        zero_action: bool = False) -> list[dict[str, Any]]:
    """One episode per target (start pose from `seed + i`), all stepped together; a record per
    episode: the target, the fingertip's final and closest distance, success, reached, the time
    to reach (s, None if never) and the reward per step. `zero_action`: the baseline that does
    nothing (the arm drifts from its random start)."""
    task = dataclasses.replace(loaded.cfg.task, episode_s=episode_s)
    envs = [make_env(task, seed=seed + i) for i in range(len(targets))]
    act_dim, obs_dim = envs[0].act_dim, envs[0].obs_dim
    policy = ZeroPolicy(act_dim) if zero_action else checkpoint.make_policy(loaded, obs_dim, act_dim)
    obs = np.stack([env.reset(seed + i, targets[i])[0] for i, env in enumerate(envs)])
    steps = task.episode_steps
    dist = np.full((len(envs), steps), np.nan)
    reward = np.zeros(len(envs))
    done = np.zeros(len(envs), bool)
    diverged = np.zeros(len(envs), bool)
    for k in range(steps):
        actions, _ = policy.act(obs, deterministic=True)
        for i, env in enumerate(envs):
            if done[i]:
                continue
            o, r, term, trunc, info = env.step(actions[i])
            obs[i] = o
            reward[i] += r
            if info.get("diverged"):
                diverged[i] = done[i] = True
                continue
            dist[i, k] = info["distance_m"]
            done[i] = term or trunc
    records = []
    for i in range(len(envs)):
        d = dist[i][np.isfinite(dist[i])]
        within = np.flatnonzero(d <= radius_m)
        final = float(d[-1]) if len(d) and not diverged[i] else None
        records.append({
            "index": i, "target": [float(x) for x in targets[i]], "final_distance_m": final,
            "min_distance_m": float(d.min()) if len(d) else None,
            "success": final is not None and final <= radius_m, "reached": bool(len(within)),
            "time_to_reach_s": float((within[0] + 1) * envs[i].dt) if len(within) else None,
            "reward_per_step": float(reward[i] / steps), "diverged": bool(diverged[i])})
    return records


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The figures over the episodes: success and reached %, the final distance's mean and median
    (mm; a diverged episode has none), the mean time to reach (s, over the episodes that did), the
    reward per step and the diverged count."""
    final = np.array([r["final_distance_m"] for r in records if r["final_distance_m"] is not None])
    times = [r["time_to_reach_s"] for r in records if r["time_to_reach_s"] is not None]
    mm = lambda f: float(1000 * f(final)) if len(final) else None  # noqa: E731
    return {"targets": len(records),
            "success_pct": 100.0 * float(np.mean([r["success"] for r in records])),
            "reached_pct": 100.0 * float(np.mean([r["reached"] for r in records])),
            "final_distance_mm": mm(np.mean), "final_distance_mm_median": mm(np.median),
            "time_to_reach_s": float(np.mean(times)) if times else None,
            "reward_per_step": float(np.mean([r["reward_per_step"] for r in records])),
            "diverged": int(sum(r["diverged"] for r in records))}


def line(s: dict[str, Any], radius_m: float) -> str:
    """The figures as one console line (after the checkpoint's name)."""
    dist = ("-" if s["final_distance_mm"] is None else
            f"{s['final_distance_mm']:.0f} mm (median {s['final_distance_mm_median']:.0f})")
    reach_t = "-" if s["time_to_reach_s"] is None else f"{s['time_to_reach_s']:.2f} s"
    return (f"success {s['success_pct']:.1f}% (fingertip within {1000 * radius_m:g} mm at the end), reached "
            f"{s['reached_pct']:.1f}% (time to reach {reach_t}), final distance {dist}, reward/step "
            f"{s['reward_per_step']:.3f}" + (f", {s['diverged']} diverged" if s["diverged"] else ""))
