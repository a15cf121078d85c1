"""`morphmimic break-probe --checkpoint X`: where an executor's pose terms break.

    morphmimic break-probe --checkpoint learner/pretrained/executor
    morphmimic break-probe --checkpoint learner/pretrained/executor --set ankle_armature=0.1 arm_armature=0.1

UniCon's constrained rule (METHOD.md B, eq. 6) ends an episode when any reward term falls below
alpha. On the evaluation's episodes (`executor_eval.run_episode`: every clip of a split,
`--starts` start frames each, the mean action), per split:
- success (all five terms) and pose success (the four pose terms), as `morphmimic evaluate`;
- of the starts that fail the pose terms: which term falls first (every pose term below alpha at
  that step counts, so the shares may add up to more than 100%) and the median step it falls at
  (an episode whose simulation diverged before any pose term fell is in neither);
- at the first step where the joint-position term (eq. 5's r_pj: every body's position relative
  to the root in the root's heading frame) falls below alpha: each body's share of its squared
  error, and how far the root is then from the reference's: its rotation angle, split into
  tilt (the rotation within the heading frame: a lean, heading-free) and heading (yaw), in
  degrees (median and quartiles); the centre of mass's horizontal offset from the reference's
  in the reference's heading frame (median forward and left, signed, and of its length; cm).
A body that leans shows as a large tilt with a small heading error and the far bodies (feet,
hands, head) carrying the joint-position error. Prints a markdown table; `--out` also writes
`break_probe.md` and `.json`.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from typing import Any

import mujoco
import numpy as np

from common.tasks.executor import rewards as rw
from learner.cli_options import parse_options
from learner.evaluation.executor import probe_cli

PROG = "morphmimic break-probe"


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """The geodesic angle (rad) between rotation matrices `[3, 3]`."""
    return float(np.arccos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0)))


def root_offsets(actual, target) -> dict[str, float]:
    """How far the character's root and centre of mass are from the target's (`BodyKin`s): the
    root rotation's angle, its tilt and heading parts (degrees), and the centre of mass's
    horizontal offset in the target's heading frame (forward, left; m)."""
    tilt = rotation_angle(actual.heading_frame.T @ actual.rot[0], target.heading_frame.T @ target.rot[0])
    yaw = rotation_angle(actual.heading_frame, target.heading_frame)
    forward, left, _ = (actual.com - target.com) @ target.heading_frame
    return {"rotation_deg": float(np.degrees(rotation_angle(actual.rot[0], target.rot[0]))),
            "tilt_deg": float(np.degrees(tilt)), "heading_deg": float(np.degrees(yaw)),
            "com_forward_m": float(forward), "com_left_m": float(left)}


class BreakHook(probe_cli.StepHook):
    """The `on_step` hook of one episode: the pose terms that fall first and when, and at the first
    joint-position break each body's squared error and the root's offsets (`root_offsets`)."""

    def __init__(self, env):
        super().__init__()
        self.pose_terms, self.alpha = rw.POSE_TERMS, env.ex.alpha
        self.first_pose: list[str] | None = None
        self.first_pose_step: int | None = None
        self.body_sq: np.ndarray | None = None
        self.offsets: dict[str, float] | None = None

    def step(self, env, terms: dict[str, float], k: int) -> None:
        if self.first_pose is None:
            fell = [n for n in self.pose_terms if terms[n] < self.alpha]
            if fell:
                self.first_pose, self.first_pose_step = fell, k
        if self.body_sq is None and terms["joint_position"] < self.alpha:
            actual, target = env.tracking_kinematics()
            quat, quat_ref = env.data.qpos[3:7], env.scheduler.frame(0).qpos[3:7]
            d = rw.yaw_aligned(actual.root_offsets(), quat, quat_ref) - target.root_offsets()  # as r_pj compares them
            self.body_sq = np.sum(d * d, axis=1)
            self.offsets = root_offsets(actual, target)


def _quartiles(xs: list[float]) -> list[float] | None:
    return [float(v) for v in np.percentile(xs, [25, 50, 75])] if xs else None


def probe_split(opened, split: str, starts: int, bodies: list[str]) -> dict[str, Any]:
    """The figures of the module docstring over one split's clips."""
    n = success = pose = 0
    first: Counter = Counter()
    first_steps: list[int] = []
    share: dict[str, float] = defaultdict(float)
    offsets: dict[str, list[float]] = defaultdict(list)
    for hook, rec in probe_cli.episodes(opened, split, starts, BreakHook):
        n += 1
        success += rec["success"]
        pose += rec["pose_success"]
        if hook.first_pose is not None:
            first.update(hook.first_pose)
            first_steps.append(hook.first_pose_step)
        if hook.body_sq is not None:
            total = float(hook.body_sq.sum())
            for name, e in zip(bodies, hook.body_sq):
                share[name] += e / total if total > 0 else 0.0
            for key, value in hook.offsets.items():
                offsets[key].append(value)
    fails, breaks = len(first_steps), len(offsets["tilt_deg"])
    com = np.hypot(offsets["com_forward_m"], offsets["com_left_m"]).tolist()
    return {
        "episodes": n, "success_pct": 100.0 * success / max(n, 1), "pose_success_pct": 100.0 * pose / max(n, 1),
        "pose_failures": fails,
        "first_term_pct": {t: 100.0 * c / fails for t, c in first.most_common()},
        "median_first_step": float(np.median(first_steps)) if first_steps else None,
        "joint_position_breaks": breaks,
        "body_share_pct": {b: 100.0 * v / breaks for b, v in sorted(share.items(), key=lambda kv: -kv[1])},
        "quartiles": {key: _quartiles(v) for key, v in {**offsets, "com_offset_m": com}.items()},
    }


def _median(r: dict, key: str, scale: float = 1.0, digits: int = 1) -> str:
    q = r["quartiles"].get(key)
    return "-" if not q else f"{scale * q[1]:.{digits}f}"


def _spread(r: dict, key: str) -> str:
    q = r["quartiles"].get(key)
    return "-" if not q else f"{q[1]:.1f} ({q[0]:.1f}-{q[2]:.1f})"


def report(name: str, rows: dict[str, dict]) -> str:
    """The markdown tables of `probe_split`'s figures per split."""
    lines = [f"# Where the pose terms of `{name}` break", "",
             "| split | episodes | success % | pose success % | pose failures | first to fall (% of them) "
             "| median step |", "|---|---|---|---|---|---|---|"]
    for split, r in rows.items():
        first = ", ".join(f"{t} {v:.0f}" for t, v in r["first_term_pct"].items()) or "-"
        step = "-" if r["median_first_step"] is None else f"{r['median_first_step']:.0f}"
        lines.append(f"| {split} | {r['episodes']} | {r['success_pct']:.1f} | {r['pose_success_pct']:.1f} | "
                     f"{r['pose_failures']} | {first} | {step} |")
    lines += ["", "At the first step where the joint-position term falls below alpha (angles in degrees, "
              "median (quartiles); centre-of-mass offset from the reference's in its heading frame, cm, median):", "",
              "| split | breaks | root rotation | tilt | heading | COM forward / left / distance "
              "| largest shares of the squared error (body %) |", "|---|---|---|---|---|---|---|"]
    for split, r in rows.items():
        top = ", ".join(f"{b} {v:.0f}" for b, v in list(r["body_share_pct"].items())[:6]) or "-"
        com = " / ".join(_median(r, k, 100.0) for k in ("com_forward_m", "com_left_m", "com_offset_m"))
        lines.append(f"| {split} | {r['joint_position_breaks']} | {_spread(r, 'rotation_deg')} | {_spread(r, 'tilt_deg')} "
                     f"| {_spread(r, 'heading_deg')} | {com} | {top} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    args = parse_options(probe_cli.ProbeOptions, argv, prog=PROG, description=__doc__)
    opened = probe_cli.open_checkpoint(PROG, args)
    model = opened.env.ref_model
    bodies = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(b)) for b in opened.env.bodies[1:]]
    rows = {split: probe_split(opened, split, args.starts, bodies) for split in args.splits}
    text = report(opened.title, rows)
    probe_cli.write(args.out, "break_probe", text, {"settings": list(args.settings), "splits": rows})
    print(text)
    return 0
