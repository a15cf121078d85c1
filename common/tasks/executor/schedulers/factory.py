"""Build any of UniCon 2020's run-time schedulers (METHOD.md B "Schedulers") for an `ExecutorEnv`:

    s = make_scheduler("keyboard", env, script=[(1.0, "left")])
    env.use_scheduler(s)          # the next env.reset begins it
    ...
    s.close() if hasattr(s, "close") else None

Each is built on the environment's own reference model (`env.ref_model`), clip cache
(`env._motion`) and control step (`env.dt`), with the lookback reactive initialization needs
and the lookahead the observation needs, so the policy sees the same frames whatever drives it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from common.motion.clip_manager import ClipManager
from common.tasks.executor.env import humanoid_clips
from common.tasks.executor.schedulers.base import DatasetScheduler, Scheduler
from common.tasks.executor.schedulers.keyboard import KeyboardScheduler
from common.tasks.executor.schedulers.stitch import StitchScheduler
from common.tasks.executor.schedulers.video import VideoScheduler

SCHEDULERS = ("dataset", "stitch", "keyboard", "video")
DEFAULT_STITCH = ("humanoid3d_walk", "humanoid3d_run", "humanoid3d_walk")
"""What the stitch scheduler plays when given no clips: a walk into a run and back."""


def make_scheduler(name: str, env: Any, **options: Any) -> Scheduler:
    """A scheduler `name` (dataset | stitch | keyboard | video) for `env` (an `ExecutorEnv`);
    `options` go to its constructor (e.g. stitch: clips, transition_s, loop; keyboard: style,
    script; video: host, port; dataset: clips, speed, at_end, max_deviation_m). Raises
    ValueError naming an unknown scheduler."""
    if name not in SCHEDULERS:
        raise ValueError(f"scheduler {name!r} is not one of {', '.join(SCHEDULERS)}")
    ex = env.ex
    frames = {"lookback": ex.rsis_frames[1] + 1, "lookahead": ex.observed_offsets[-1] + 1}
    if name == "dataset":
        return _dataset(env, frames, **options)
    if name == "stitch":
        clips = options.pop("clips", ()) or DEFAULT_STITCH
        if isinstance(clips, str) or not isinstance(clips, (tuple, list)):
            raise ValueError(f"stitch clips {clips!r} must be a list of clip ids (or (id, start_s, end_s) items)")
        clips = tuple(clips)
        options.setdefault("speed", ex.speed)
        return StitchScheduler(env.ref_model, env._motion, env.dt, clips, known_ids=_known_clips(env), **frames, **options)
    if name == "keyboard":
        return KeyboardScheduler(env.ref_model, env._motion, env.dt, **frames, **options)

    # NOTE: the playback delay covers the lookahead plus one step for the centred velocity, so
    # every frame the observation asks for is interpolated between received frames.
    options.setdefault("delay_s", max(0.1, (ex.observed_offsets[-1] + 2) * env.dt))
    return VideoScheduler(env.ref_model, env.dt, **options)


def _dataset(env: Any, frames: dict, *, clips: tuple[str, ...] = (), **options: Any) -> Scheduler:
    """A dataset scheduler over `clips` (drawn uniformly) or, by default, the environment's own
    `ClipManager` (the task's clips by the motion balancer); options default to the task's
    (speed, at_end, target velocity window)."""
    if clips:
        known = _known_clips(env)
        unknown = [c for c in clips if c not in known]
        if unknown:
            raise ValueError(f"clips {unknown} do not play on the humanoid; choose from: {', '.join(known[:8])}, ...")
        manager = ClipManager.with_probabilities(tuple(clips), np.full(len(clips), 1.0 / len(clips)),
                                                 env.clip_manager.duration_s)
    else:
        manager = env.clip_manager
    options.setdefault("speed", env.ex.speed)
    options.setdefault("at_end", env.ex.at_clip_end)
    options.setdefault("velocity_window", env.ex.target_velocity_window)
    return DatasetScheduler(env.ref_model, env._motion, manager, None, env.dt, **frames, **options)


def _known_clips(env: Any) -> list[str]:
    """Every clip id `env` can play: the humanoid's library clips, their mirror images and the
    clips registered on it."""
    known = [c for c, _ in humanoid_clips(mirror=True, library="full")]
    return known + [c for c in env._motions if c not in set(known)]
