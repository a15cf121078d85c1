"""`morphmimic velocity-probe --checkpoint X`: where an executor's joint-velocity term breaks.

    morphmimic velocity-probe --checkpoint learner/pretrained/executor               # ankles left out
    morphmimic velocity-probe --checkpoint learner/pretrained/executor --leave-out ankle knee
    morphmimic velocity-probe --checkpoint learner/pretrained/executor --set ankle_armature=0.1

UniCon's constrained rule (METHOD.md B, eq. 6) ends an episode when any of the five reward terms
falls below alpha; the joint-velocity term r_wj = exp(-k sum ||qdot - qdot~||^2) (eq. 5) sums
over every joint DOF, so one fast-moving light segment can break it. On the evaluation's episodes
(`executor_eval.run_episode`: every clip of a split, `--starts` start frames each, the mean
action), per split:
- success: UniCon's rule (all five terms); pose success: the four pose terms;
- success with the `--leave-out` joints' DOF left out of the velocity term (analysis only: the
  pose terms and the other DOF's velocity term must still stay at or above alpha);
- at the first step of each episode where r_wj falls below alpha: the median summed squared
  error ((rad/s)^2; the term breaks above -ln(alpha)/k), the share of it per joint, and how often
  a body of a left-out joint touches something then (for the ankles: a foot on the floor);
- over every step, the left-out DOF's mean squared velocity error ((rad/s)^2 per DOF) while
  their own body touches something and while it is free (a foot on the floor or in the air).
Prints a markdown table; `--out` also writes `velocity_probe.md` and `.json`.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from typing import Annotated, Any

import mujoco
import numpy as np

from common.config_limits import validated
from common.tasks.executor import rewards as rw
from learner.cli_options import parse_options, refuse, value_list
from learner.evaluation.executor import probe_cli

PROG = "morphmimic velocity-probe"


@validated
@dataclass(kw_only=True)
class VelocityProbeOptions(probe_cli.ProbeOptions):
    leave_out: Annotated[tuple[str, ...], value_list(str, "JOINT", nargs="+")] = ("ankle",)
    """Joints (by part of their name) left out of the velocity term for the third column."""


def joint_of_dof(model) -> list[str]:
    """The joint name of each non-root DOF `[nv - 6]`."""
    return [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, int(model.dof_jntid[d])) for d in range(6, model.nv)]


def left_out_mask(joints: list[str], patterns: list[str]) -> np.ndarray:
    """DOF mask `[nv - 6]` of the joints whose name contains one of `patterns`; ValueError naming a
    pattern that matches no joint, with the joints there are."""
    mask = np.zeros(len(joints), dtype=bool)
    for pat in patterns:
        if not pat.strip():
            raise ValueError(f"--leave-out {pat!r}: give part of a joint name; the joints are {', '.join(sorted(set(joints)))}")
        hit = np.array([pat in name for name in joints])
        if not hit.any():
            raise ValueError(f"--leave-out {pat!r} matches no joint; the joints are {', '.join(sorted(set(joints)))}")
        mask |= hit
    return mask


class EpisodeProbe(probe_cli.StepHook):
    """The `on_step` hook of one episode: the velocity error per DOF at the first step where r_wj
    falls below alpha, and whether the episode holds with the left-out DOF ignored."""

    def __init__(self, env, left_out: np.ndarray):
        super().__init__()
        self.pose_terms, self.k, self.alpha = rw.POSE_TERMS, env.ex.reward_scales[4], env.ex.alpha
        self.left_out = left_out
        dof_body = env.ref_model.jnt_bodyid[env.ref_model.dof_jntid[6:]]
        self.left_out_bodies = {int(b) for b in dof_body[left_out]}
        self.dof_body = dof_body
        self.first_break: np.ndarray | None = None
        self.touching = False
        self.holds_without = True
        self.sq_sum = {True: 0.0, False: 0.0}  # the left-out DOF's squared error summed, by body touching
        self.dof_steps = {True: 0, False: 0}

    def step(self, env, terms: dict[str, float], k: int) -> None:
        err = (env.data.qvel[6 : env.nv] - env.scheduler.frame(0).qvel[6:]) ** 2
        d, m = env.data, env.model
        touched = {int(m.geom_bodyid[g]) for c in d.contact[: d.ncon] for g in (c.geom1, c.geom2)}
        for i in np.flatnonzero(self.left_out):
            on = int(self.dof_body[i]) in touched
            self.sq_sum[on] += float(err[i])
            self.dof_steps[on] += 1
        kept = float(err[~self.left_out].sum())
        if any(terms[n] < self.alpha for n in self.pose_terms) or math.exp(-self.k * kept) < self.alpha:
            self.holds_without = False
        if self.first_break is None and terms["joint_velocity"] < self.alpha:
            self.first_break = err
            self.touching = bool(self.left_out_bodies & touched)


def probe_split(opened, split: str, starts: int, left_out: np.ndarray, joints: list[str]) -> dict[str, Any]:
    """The figures of the module docstring over one split's clips."""
    n = success = pose = without = touching = 0
    breaks: list[float] = []
    share: dict[str, float] = defaultdict(float)
    sq_sum, dof_steps = {True: 0.0, False: 0.0}, {True: 0, False: 0}
    for hook, rec in probe_cli.episodes(opened, split, starts, lambda env: EpisodeProbe(env, left_out)):
        n += 1
        success += rec["success"]
        pose += rec["pose_success"]
        without += hook.holds_without and not rec["diverged"]
        for on in (True, False):
            sq_sum[on] += hook.sq_sum[on]
            dof_steps[on] += hook.dof_steps[on]
        if hook.first_break is not None:
            total = float(hook.first_break.sum())
            breaks.append(total)
            touching += hook.touching
            for name, e in zip(joints, hook.first_break):
                share[name] += e / total
    pct = lambda x: 100.0 * x / max(n, 1)  # noqa: E731
    return {
        "episodes": n, "success_pct": pct(success), "pose_success_pct": pct(pose), "success_left_out_pct": pct(without),
        "breaks": len(breaks), "median_break_error": float(np.median(breaks)) if breaks else None,
        "touching_at_break_pct": 100.0 * touching / len(breaks) if breaks else None,
        "joint_share_pct": {j: 100.0 * v / len(breaks) for j, v in sorted(share.items(), key=lambda kv: -kv[1])},
        "left_out_sq_error_touching": sq_sum[True] / dof_steps[True] if dof_steps[True] else None,
        "left_out_sq_error_free": sq_sum[False] / dof_steps[False] if dof_steps[False] else None,
        "left_out_touching_pct": 100.0 * dof_steps[True] / max(1, dof_steps[True] + dof_steps[False]),
    }


def report(name: str, left_out: list[str], threshold: float, rows: dict[str, dict]) -> str:
    """The markdown table of `probe_split`'s figures per split."""
    lines = [f"# Where the joint-velocity term of `{name}` breaks", "",
             f"Left out of the velocity term for the third column: joints matching {', '.join(left_out)}. "
             f"The term falls below alpha when the summed squared error exceeds {threshold:.1f} (rad/s)^2.", "",
             "| split | episodes | success % | success %, left out | pose success % | episodes where r_wj breaks "
             "| median error there | left-out body touching % | largest shares of the error (joint %) "
             "| left-out DOF's mean squared error, touching / free (% of DOF-steps touching) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for split, r in rows.items():
        top = ", ".join(f"{j} {v:.0f}" for j, v in list(r["joint_share_pct"].items())[:5])
        med = "-" if r["median_break_error"] is None else f"{r['median_break_error']:.1f}"
        touch = "-" if r["touching_at_break_pct"] is None else f"{r['touching_at_break_pct']:.0f}"
        on, off = (r.get(f"left_out_sq_error_{w}") for w in ("touching", "free"))
        split_err = "-" if on is None or off is None else f"{on:.1f} / {off:.1f} ({r['left_out_touching_pct']:.0f}%)"
        lines.append(f"| {split} | {r['episodes']} | {r['success_pct']:.1f} | {r['success_left_out_pct']:.1f} | "
                     f"{r['pose_success_pct']:.1f} | {r['breaks']} | {med} | {touch} | {top} | {split_err} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    args = parse_options(VelocityProbeOptions, argv, prog=PROG, description=__doc__)
    opened = probe_cli.open_checkpoint(PROG, args)
    if opened.loaded.cfg.task.executor.joint_velocity != "instant":
        refuse(PROG, "joint_velocity = step_mean: the probe reads the simulator's instant joint velocities, "
                     "which that term does not compare; probe with --set joint_velocity=instant")
    joints = joint_of_dof(opened.env.ref_model)
    try:
        mask = left_out_mask(joints, list(args.leave_out))
    except ValueError as exc:
        refuse(PROG, str(exc))
    rows = {split: probe_split(opened, split, args.starts, mask, joints) for split in args.splits}
    ex = opened.loaded.cfg.task.executor
    text = report(opened.title, list(args.leave_out), -math.log(ex.alpha) / ex.reward_scales[4], rows)
    probe_cli.write(args.out, "velocity_probe", text,
                    {"leave_out": list(args.leave_out), "settings": list(args.settings), "splits": rows})
    print(text)
    return 0
