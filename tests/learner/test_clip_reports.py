"""From unrolls to the sampler: the learner sums the actors' clip segments and keeps the failed
ones' clip times, and its sampler handle sends them over the real socket (a serial-mode
sampler on 127.0.0.1), only for clips the sampler draws and only when it keeps time bins; and
a short executor run with failure weighting and time bins, end to end."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from common import wire
from learner import checkpoint
from learner.config import RunConfig
from learner.learner import Learner
from learner.presets import PRESETS
from learner.sampler_handle import SamplerHandle
from learner.train import train
from sampler.config import SamplerConfig
from sampler.shape_sampler import state_from_torch

CLIPS = [("long", "root/a/x"), ("other", "root/b")]
DURATIONS = {"long": 4.0, "other": 2.0}


def _unroll(learner: Learner, clips: list[str], tracked: list[int], times: list[float]) -> wire.UnrollMsg:
    t, n = 2, 1
    z = lambda *shape: np.zeros(shape, np.float32)  # noqa: E731
    return wire.UnrollMsg(actor_id=0, seq=0, policy_version=0, obs=z(t, n, learner.obs_dim), next_obs=z(t, n, learner.obs_dim),
                          actions=z(t, n, learner.act_dim), logp=z(t, n), rewards=z(t, n),
                          terminated=np.zeros((t, n), bool), truncated=np.zeros((t, n), bool),
                          params=z(t, n, learner.space.dim) + learner.space.default_array.astype(np.float32),
                          segment_clips=clips, segment_tracked=tracked, segment_times=times)


def test_failed_segments_reach_the_time_bins_and_counts_the_outcomes():
    learner = Learner(RunConfig())
    learner.record_episodes([_unroll(learner, ["long", "long", "other", "gone"], [0, 1, 0, 0], [3.2, 4.0, 0.5, 1.0]),
                             _unroll(learner, ["long"], [0], [])])  # a sender without times: counted, no time
    segments = learner.take_clip_segments()
    assert segments == (["gone", "long", "other"], [1, 3, 1], [0, 1, 0])
    failures = learner.take_clip_failures()
    assert failures == (["long", "other", "gone"], [3.2, 0.5, 1.0])
    assert learner.take_clip_failures() == ([], [])
    cfg = SamplerConfig(n_mcmc=16, n_chains=4, burn_in=4, vm_fit_steps=1, probe_points=8, time_bin_s=0.5)
    space = learner.space
    for time_bin_s, seen in ((0.5, 2.0), (0.0, None)):
        handle = SamplerHandle.start(dataclasses.replace(cfg, time_bin_s=time_bin_s), space, CLIPS, None,
                                     durations=DURATIONS)
        try:
            params = np.tile(space.default_array, (3, 1)).astype(np.float32)
            stats = handle.report_and_tick(params, np.ones(3, np.float32), 1, segments, failures)
            assert stats["sampler/clips/segments_seen"] == 4  # "gone" is not sent
            assert stats["sampler/learner_call_failures"] == 0  # nothing refused
            assert stats.get("sampler/clips/time/fails_seen") == seen  # sent only to a sampler with time bins
        finally:
            handle.stop()


def test_an_executor_run_samples_where_it_fails_and_logs_it(tmp_path):
    """`--task.executor.at-clip-end stop --sampler.clip-weighting failure --sampler.time-bin-s
    0.5`: failure times travel from the environments to the sampler's bins (in the checkpoint's
    sampler state), none is refused, and TensorBoard has each class's and clip's start share and
    success."""
    base = PRESETS["executor-tiny"][1]
    cfg = dataclasses.replace(
        base, runs_dir=str(tmp_path), quiet=True, mode="serial", max_iterations=2, total_env_steps=10**6,
        task=dataclasses.replace(base.task, executor=dataclasses.replace(base.task.executor, at_clip_end="stop")),
        sampler=dataclasses.replace(base.sampler, clip_weighting="failure", time_bin_s=0.5))
    assert train(cfg) == 0
    state = state_from_torch(checkpoint.load_latest(tmp_path / "executor-tiny" / "ckpt")[1]["sampler"])
    bins = state["meta"]["time_bins"]
    assert bins["bin_s"] == 0.5 and bins["seen"] > 0 and bins["refused"] == 0
    assert state["arrays"]["clips/time_fails"].sum() > 0
    tb = EventAccumulator(str(tmp_path / "executor-tiny" / "tb"), size_guidance={"scalars": 0})
    tb.Reload()
    tags = set(tb.Tags()["scalars"])
    assert {"sampler/clips/class/root/locomotion/walk/starts_pct", "sampler/clips/clip/humanoid3d_walk/starts_pct",
            "sampler/clips/time/entropy", "sampler/clips/time/fails_seen"} <= tags
    assert any(t.endswith("/success_pct") and t.startswith("sampler/clips/class/") for t in tags)
    shares = [tb.Scalars(t)[-1].value for t in tags if t.startswith("sampler/clips/class/") and t.endswith("/starts_pct")]
    assert sum(shares) == pytest.approx(100.0)
