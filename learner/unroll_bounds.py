"""An unroll's content held to what its task can produce, before anything learns from it.

The codec (`common.wire`) checks types, shapes and finiteness; it cannot know that a reach arm
never observes 3e38 or earns 1e30 in one step. `UnrollBounds.check` holds each decoded unroll to
the task's declared bounds (`common.tasks.content_bounds.ContentBounds`), its parameter box and
clips, and to what T x N steps can hold. An unroll that fails is dropped whole by the transport
and counted by reason under `rejected/bounds_<reason>` (TensorBoard: `wire/rejected/bounds_*`),
so the observation normalizer, the value targets, the episode counters and the sampler's value
report only ever see unrolls an honest actor could have sent:

    bounds_obs          an observation component beyond the task's magnitude
    bounds_reward       a reward outside the task's per-step range
    bounds_params       a parameter vector outside the sampler's box (it would refuse the report)
    bounds_episodes     episode ends and lengths that do not match the done flags
    bounds_returns      an episode return its rewards and length cannot add up to
    bounds_divergences  more divergences than terminated steps (each divergence terminates one)
    bounds_segments     more clip segments than 2 per step and environment, or a clip the task lacks
                        (of a segment or of a step's episode, `step_clips`), or step clips of
                        another shape than the steps' or indexing no clip
    bounds_outages      more sampler outages than the actor's draws so far (one per episode start)
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from common import wire
from common.params import ParamError, ParamSpace
from common.tasks.base import TaskConfig
from common.tasks.content_bounds import ContentBounds
from common.tasks.registry import task_bounds, task_clips, task_space

REASONS = ("obs", "reward", "params", "episodes", "returns", "divergences", "segments", "outages")
"""The `bounds_<reason>` counter buckets, in the order the checks run."""
SEGMENTS_PER_STEP = 2
"""Clip segments one environment can end in one step: a clip switch and the episode's end."""


class BoundsError(wire.WireError):
    """An unroll outside its task's bounds; `kind` is `bounds_<reason>`."""


class UnrollBounds:
    """The bounds of one task's unrolls; `check` raises `BoundsError` for the first one broken."""

    def __init__(self, bounds: ContentBounds, space: ParamSpace, clip_ids: Iterable[str] = (), task: str = ""):
        self.bounds, self.space, self.task = bounds, space, task
        self.clip_ids = frozenset(clip_ids)
        self.reward_tol = 1e-6 * bounds.reward_scale
        """float32 rounding of a reward at a bound."""

    @classmethod
    def for_task(cls, task: TaskConfig) -> "UnrollBounds":
        return cls(task_bounds(task), task_space(task), [cid for cid, _ in task_clips(task)], task.name)

    def _fail(self, msg: wire.UnrollMsg, reason: str, what: str) -> BoundsError:
        task = f" (task {self.task})" if self.task else ""
        return BoundsError(f"unroll {msg.seq} of actor {msg.actor_id}: {what}{task}; dropped whole", f"bounds_{reason}")

    def check(self, msg: wire.UnrollMsg) -> None:
        """Raise `BoundsError` naming the first value no honest actor of this task could send."""
        b = self.bounds
        for name in ("obs", "next_obs"):
            arr = np.abs(getattr(msg, name))
            if arr.size and float(arr.max()) > b.obs_max_abs:
                at = np.unravel_index(int(arr.argmax()), arr.shape)
                raise self._fail(msg, "obs", f"{name}{list(map(int, at))} = {float(getattr(msg, name)[at]):g}; "
                                             f"allowed: |{name}| <= {b.obs_max_abs:g}")
        r = msg.rewards
        if r.size and (r.min() < b.reward_min - self.reward_tol or r.max() > b.reward_max + self.reward_tol):
            at = np.unravel_index(int(np.argmax(np.maximum(b.reward_min - r, r - b.reward_max))), r.shape)
            raise self._fail(msg, "reward", f"rewards{list(map(int, at))} = {float(r[at]):g}; "
                                            f"allowed: [{b.reward_min:g}, {b.reward_max:g}] per step")
        try:
            self.space.validate_batch(msg.params.reshape(-1, msg.params.shape[-1]))
        except ParamError as exc:
            raise self._fail(msg, "params", f"params {exc}") from None
        self._check_episodes(msg)
        terminated = int(msg.terminated.sum())
        if msg.divergences > terminated:
            raise self._fail(msg, "divergences", f"divergences = {msg.divergences}; allowed: at most the "
                                                 f"{terminated} terminated steps")
        steps = msg.rewards.size
        if len(msg.segment_clips) > SEGMENTS_PER_STEP * steps:
            raise self._fail(msg, "segments", f"{len(msg.segment_clips)} clip segments; allowed: at most "
                                              f"{SEGMENTS_PER_STEP * steps} ({SEGMENTS_PER_STEP} per step of {steps})")
        unknown = next((c for c in msg.segment_clips if c not in self.clip_ids), None)
        if unknown is not None:
            allowed = f"one of the task's {len(self.clip_ids)} clips" if self.clip_ids else "none (the task has no clips)"
            raise self._fail(msg, "segments", f"segment clip {unknown[:64]!r}; allowed: {allowed}")
        self._check_step_clips(msg)
        n_envs = msg.rewards.shape[1] if msg.rewards.ndim == 2 else 0
        draws = n_envs + (msg.seq + 1) * steps
        if msg.sampler_outages > draws:
            raise self._fail(msg, "outages", f"sampler_outages = {msg.sampler_outages}; allowed: at most {draws} "
                                             f"(one per episode start: {n_envs} first ones and one per step "
                                             f"of unrolls 0..{msg.seq})")

    def _check_step_clips(self, msg: wire.UnrollMsg) -> None:
        """`step_clips` is empty or `[T, N]`, each entry -1 or an index into `clip_names`, which
        name distinct clips of the task."""
        names, idx = msg.clip_names, msg.step_clips
        unknown = next((c for c in names if c not in self.clip_ids), None)
        if unknown is not None:
            allowed = f"one of the task's {len(self.clip_ids)} clips" if self.clip_ids else "none (the task has no clips)"
            raise self._fail(msg, "segments", f"clip_names entry {unknown[:64]!r}; allowed: {allowed}")
        if len(set(names)) != len(names):
            raise self._fail(msg, "segments", "clip_names names a clip twice; allowed: each once")
        if idx.size == 0 and idx.ndim == 2:
            return
        if idx.shape != msg.rewards.shape:
            raise self._fail(msg, "segments", f"step_clips of shape {list(idx.shape)}; allowed: empty or "
                                              f"{list(msg.rewards.shape)}, one per step")
        if int(idx.min()) < -1 or int(idx.max()) >= len(names):
            bad = int(idx.min()) if int(idx.min()) < -1 else int(idx.max())
            raise self._fail(msg, "segments", f"step_clips entry {bad}; allowed: -1 (none) or an index in "
                                              f"[0, {len(names)}) into clip_names")

    def _check_episodes(self, msg: wire.UnrollMsg) -> None:
        """Each episode that ended here ends at a done flag, in the actor's order (step, then
        environment); one that also began here is exactly as long as the steps since its
        environment's previous end, and its return is the sum of its rewards; one that began
        earlier is longer than the steps it has here, and its return is those rewards plus what
        its earlier steps could earn."""
        b = self.bounds
        both = msg.terminated & msg.truncated
        if both.any():
            t, i = (int(x[0]) for x in np.nonzero(both))
            raise self._fail(msg, "episodes", f"step [{t}, {i}] is both terminated and truncated; an episode ends once")
        ends = np.argwhere(msg.terminated | msg.truncated)  # row-major: the order the actor appends in
        if len(ends) != len(msg.episode_returns):
            raise self._fail(msg, "episodes", f"{len(msg.episode_returns)} episode returns for {len(ends)} done "
                                              "flags; allowed: one per done flag")
        sums = np.vstack([np.zeros((1, msg.rewards.shape[1])), np.cumsum(msg.rewards, axis=0, dtype=np.float64)])
        last_end: dict[int, int] = {}
        for k, (t, i) in enumerate(ends.tolist()):
            length, ret = msg.episode_lengths[k], msg.episode_returns[k]
            start = last_end.get(i, -1) + 1
            here = t + 1 - start
            if i in last_end and length != here:
                raise self._fail(msg, "episodes", f"episode_lengths[{k}] = {length}; that episode ran steps "
                                                  f"{start}..{t} of environment {i}, so allowed: {here}")
            if not here <= length <= b.episode_steps:
                raise self._fail(msg, "episodes", f"episode_lengths[{k}] = {length}; allowed: [{here}, "
                                                  f"{b.episode_steps}] (its steps here, the task's horizon)")
            known = float(sums[t + 1, i] - sums[start, i])
            earlier = length - here
            tol = 1e-6 * length * b.reward_scale + 1e-6
            lo, hi = known + earlier * b.reward_min - tol, known + earlier * b.reward_max + tol
            if not lo <= ret <= hi:
                raise self._fail(msg, "returns", f"episode_returns[{k}] = {ret:g} over {length} steps; allowed: "
                                                 f"[{lo:g}, {hi:g}] (its rewards here and the per-step range)")
            last_end[i] = t
