"""`morphmimic bench shape-references`: what a vary-shape executor reset pays for its reference,
the clip retargeted whole at once against its frames made as the episode reads them.

`executor-shape` draws a body per episode and tracks the episode's clip retargeted onto it
(`common.tasks.executor.bodies.ShapedReferences`); in training nearly every (clip, shape) is new,
so nearly every reset builds one. In one process, on the same new (clip, shape, start) triples,
each reset run both ways in turn (the order alternating, the same seed), the reference cache emptied before
each and the bodies built beforehand (a body's build is not what is compared):
- whole clip: `retarget_frames` and the floor lift over every frame at the reset (`lazy` off);
- on demand: the frames the scheduler reads, made when it reads them (`lazy_retarget`), at the
  reset the first chunk of the schedule, later ones inside the steps that reach them.
Each reset is followed by its episode with zero actions (ended by the task, or cut at
`--episode-steps`). Printed: the reset's and the episode's mean CPU time both ways and their
ratios, a control step (the whole-clip runs' steps, which make no frames), the reset in control
steps and the resets' share of the episodes' time, the frames made per reference, and whether
the two references agree frame for frame (each on-demand reference completed afterwards and
compared bit for bit) and the two episodes step for step (observations and rewards). CPU time of this process (`time.process_time`), so that a loaded machine's
waits stay out of it; read the ratios, not the milliseconds.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from common.config_limits import SEED, Limit, at_least, check_limits, validated
from learner.cli_options import CommaStrs, parse_options

CLIPS = ("humanoid/bandai/dataset-1_walk-left_angry_001", "humanoid3d_walk", "humanoid3d_backflip")
PRESET = "executor-shape"


def bench(clips: tuple[str, ...], library: int, pairs: int, episode_steps: int, seed: int) -> dict[str, object]:
    """The figures the module docstring lists, as a dict (times in ms)."""
    from common.tasks.executor.env import ExecutorEnv, executor_clips  # lazy: start-up time of --help (mujoco)
    from learner.presets import PRESETS  # lazy: start-up time of --help (torch)

    rng = np.random.default_rng(seed)
    task = PRESETS[PRESET][1].task
    chosen = list(clips)
    if library:
        pool = [c for c, *_ in executor_clips(task) if c not in chosen]
        chosen += [pool[i] for i in rng.choice(len(pool), size=min(library, len(pool)), replace=False)]
    ex = dataclasses.replace(task.executor, clips=tuple(chosen), shape_cache=min(4096, pairs + 2))
    env = ExecutorEnv(dataclasses.replace(task, executor=ex), seed=seed)
    refs = env._references
    shapes = env.space.uniform(rng, pairs)
    triples = []
    for n, shape in enumerate(shapes):
        clip = chosen[n % len(chosen)]
        duration = env._source(clip).duration_s
        refs.contacts(clip)
        env._bodies.get(shape)
        triples.append((clip, shape, float(rng.uniform(0.0, max(duration - 3 * env.dt, 0.0)))))
    zero = np.zeros(env.act_dim)
    got = {mode: {"reset": 0.0, "episode": 0.0, "steps": 0, "frames": 0} for mode in ("whole", "demand")}
    same = same_episodes = 0
    for n, (clip, shape, start) in enumerate(triples):
        digests = {}
        for mode in (("whole", "demand") if n % 2 == 0 else ("demand", "whole")):
            refs.lazy = mode == "demand"
            refs._cache.clear()
            digest = hashlib.sha256()
            t0 = time.process_time()
            obs, _ = env.reset(seed + n, shape, clip_id=clip, start_s=start)
            t1 = time.process_time()
            digest.update(obs.tobytes())
            for k in range(episode_steps):
                obs, reward, terminated, truncated, _ = env.step(zero)
                digest.update(obs.tobytes() + np.float64(reward).tobytes())
                if terminated or truncated:
                    break
            t2 = time.process_time()
            digests[mode] = digest.digest()
            g = got[mode]
            g["reset"] += t1 - t0
            g["episode"] += t2 - t0
            g["steps"] += k + 1
            motion = env._motion(clip)
            made = getattr(getattr(motion, "retarget", None), "done", None)
            g["frames"] += int(made.sum()) if made is not None else len(motion.qpos_frames)
            if mode == "demand":
                lazy_frames = motion.qpos_frames
        same_episodes += digests["whole"] == digests["demand"]
        refs.lazy = False
        same += bool(np.array_equal(lazy_frames, env._motion(clip).qpos_frames))
    refs.lazy = True
    # the reset's own part: the same resets with their references made and cached
    cached = 0.0
    for clip, shape, start in triples:
        refs._cache.clear()
        env.reset(seed, shape, clip_id=clip, start_s=start)
        env._motion(clip).qpos_frames  # every frame made
        t1 = time.process_time()
        env.reset(seed, shape, clip_id=clip, start_s=start)
        cached += time.process_time() - t1
    out: dict[str, object] = {"clips": chosen, "pairs": pairs, "same": same, "same_episodes": same_episodes}
    for mode, g in got.items():
        out[f"{mode}_reset_ms"] = 1e3 * g["reset"] / pairs
        out[f"{mode}_episode_ms"] = 1e3 * g["episode"] / pairs
        out[f"{mode}_frames"] = g["frames"] / pairs
        out[f"{mode}_steps"] = g["steps"] / pairs
    out["step_ms"] = 1e3 * (got["whole"]["episode"] - got["whole"]["reset"]) / got["whole"]["steps"]
    out["cached_reset_ms"] = 1e3 * cached / pairs
    return out


@validated
@dataclass
class ShapeReferenceBenchOptions:
    clips: CommaStrs = CLIPS
    """Comma-separated clips (library ids) the pairs take in turn."""
    library: int = 6
    """Also this many clips drawn from the preset's training split."""
    pairs: int = 24
    """New (clip, shape, start) triples, each reset both ways."""
    episode_steps: int = 300
    """Cut an episode after this many control steps (zero actions end one in about 46)."""
    seed: int = 0
    """Seed of the clip draw, shapes and starts."""

    LIMITS: ClassVar[dict[str, Limit]] = {"library": at_least(0), "pairs": at_least(1), "episode_steps": at_least(1),
                                          "seed": SEED}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        if not self.clips and not self.library:
            raise ValueError("give some --clips or --library N > 0")
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(ShapeReferenceBenchOptions, argv, prog="morphmimic bench shape-references",
                         description=__doc__.split("\n\n")[0])
    r = bench(tuple(args.clips), args.library, args.pairs, args.episode_steps, args.seed)
    step = r["step_ms"]
    print(f"{PRESET}: {r['pairs']} new (clip, shape, start) triples over {len(r['clips'])} clips, zero actions, "
          f"CPU ms of this process")
    header = f"{'':<30} {'whole clip':>11} {'on demand':>11} {'ratio':>7}"
    print(header)
    print("-" * len(header))
    for name, key in (("reset on a new (clip, shape)", "reset_ms"), ("episode (reset + its steps)", "episode_ms")):
        a, b = r[f"whole_{key}"], r[f"demand_{key}"]
        print(f"{name:<30} {a:>11.2f} {b:>11.2f} {a / b:>7.2f}")
    print(f"{'reset, its reference cached':<30} {r['cached_reset_ms']:>11.2f}")
    print(f"{'control step':<30} {step:>11.3f}")
    print(f"{'reset / control step':<30} {r['whole_reset_ms'] / step:>11.1f} {r['demand_reset_ms'] / step:>11.1f}")
    print(f"{'reference / control step':<30} {(r['whole_reset_ms'] - r['cached_reset_ms']) / step:>11.1f} "
          f"{(r['demand_reset_ms'] - r['cached_reset_ms']) / step:>11.1f}")
    shares = [r[f"{m}_reset_ms"] / r[f"{m}_episode_ms"] for m in ("whole", "demand")]
    print(f"{'resets share of episode time':<30} {shares[0]:>11.0%} {shares[1]:>11.0%}")
    print(f"{'frames made per reference':<30} {r['whole_frames']:>11.0f} {r['demand_frames']:>11.0f}")
    print(f"{'steps per episode':<30} {r['whole_steps']:>11.1f} {r['demand_steps']:>11.1f}")
    print(f"references bit for bit equal: {r['same']} of {r['pairs']}; episodes (observations, rewards) equal: "
          f"{r['same_episodes']} of {r['pairs']}")
    return 0 if r["same"] == r["same_episodes"] == r["pairs"] else 1
