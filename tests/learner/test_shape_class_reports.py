"""From actors' step clips to a sampler over (shape, class) (`--sampler.shape-by-class`, issue 55
item 2): the unroll bounds check each step's clip, the learner pairs each value with its
episode's clip, and its sampler handle sends them (over 127.0.0.1) only to a sampler that fits
over classes, leaving out and counting the pairs without a clip it draws."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from common import wire
from common.tasks.registry import task_bounds, task_space
from learner.learner import Learner
from learner.presets import PRESETS
from learner.sampler_handle import SamplerHandle
from learner.unroll_bounds import BoundsError, UnrollBounds
from sampler.config import SamplerConfig

CFG = PRESETS["reach-tiny"][1]
CLIPS = [("walk", "root/loco/walk"), ("flip", "root/acro/flip")]


def unroll(learner: Learner, names: list[str], step_clips: np.ndarray | None, seed: int = 0, t: int = 4,
           n: int = 2) -> wire.UnrollMsg:
    z = lambda *shape: np.zeros(shape, np.float32)  # noqa: E731
    rng = np.random.default_rng(seed)
    extra = {} if step_clips is None else {"clip_names": names, "step_clips": step_clips.astype(np.int32)}
    return wire.UnrollMsg(actor_id=0, seq=0, policy_version=0, obs=rng.normal(0, 1, (t, n, learner.obs_dim)).astype(np.float32),
                          next_obs=z(t, n, learner.obs_dim), actions=z(t, n, learner.act_dim), logp=z(t, n), rewards=z(t, n),
                          terminated=np.zeros((t, n), bool), truncated=np.zeros((t, n), bool),
                          params=z(t, n, learner.space.dim) + learner.space.default_array.astype(np.float32), **extra)


def test_step_clips_are_checked_against_the_steps_and_the_task():
    learner = Learner(CFG)
    bounds = UnrollBounds(task_bounds(CFG.task), task_space(CFG.task), [c for c, _ in CLIPS])
    good = unroll(learner, ["flip", "walk"], np.array([[0, 1]] * 3 + [[-1, 1]]))
    bounds.check(wire.decode(wire.encode(good)))
    bounds.check(unroll(learner, [], None))  # a sender that does not tell
    for names, steps, why in ((["flip"], np.array([[0, 1]] * 4), r"step_clips entry 1; allowed: -1 \(none\)"),
                              (["flip"], np.array([[0, -2]] * 4), "step_clips entry -2"),
                              (["flip"], np.zeros((3, 2)), r"step_clips of shape \[3, 2\]; allowed: empty or \[4, 2\]"),
                              (["jump"], np.zeros((4, 2)), "clip_names entry 'jump'"),
                              (["flip", "flip"], np.zeros((4, 2)), "names a clip twice")):
        with pytest.raises(BoundsError, match=why) as err:
            bounds.check(unroll(learner, names, steps))
        assert err.value.kind == "bounds_segments"


def test_each_value_pair_goes_with_its_episodes_clip_to_a_sampler_over_classes():
    learner = Learner(CFG)
    a = unroll(learner, ["walk", "flip"], np.array([[0, 1]] * 4), seed=1)
    b = unroll(learner, ["flip"], np.array([[0, -1]] * 4), seed=2)
    c = unroll(learner, [], None, seed=3)
    params, values, clips = learner.value_triples([a, b, c], 100)
    assert len(clips) == len(values) == 24
    obs = np.concatenate([u.obs.reshape(-1, learner.obs_dim) for u in (a, b, c)])
    row_values = learner.ppo.values_of(torch.as_tensor(obs, device=learner.device)).cpu().numpy()
    row_clips = ["walk", "flip"] * 4 + ["flip", ""] * 4 + ["", ""] * 4  # [T, N] row-major, as the obs
    for v, clip in zip(values, clips):  # each value is its own step's, and goes with that step's clip
        assert row_clips[int(np.argmin(np.abs(row_values - v)))] == clip
    assert clips.count("walk") == 4 and clips.count("flip") == 8 and clips.count("") == 12
    space = learner.space
    cfg = SamplerConfig(n_mcmc=16, n_chains=4, burn_in=4, vm_fit_steps=1, probe_points=8)
    for by_class, sent in ((True, 12), (False, 24)):
        handle = SamplerHandle.start(dataclasses.replace(cfg, shape_by_class=by_class), space, CLIPS, None)
        try:
            stats = handle.report_and_tick(params, values, 1, pair_clips=clips)
            assert stats["sampler/vm/pairs_seen"] == sent and stats["sampler/learner_call_failures"] == 0
            assert handle.counters()["faults/value_pairs_lost"] == 24 - sent  # no clip: no class to fit it under
            if by_class:
                assert "sampler/vm/class/root/loco/walk/vbar" in stats
        finally:
            handle.stop()


def test_an_executor_run_fits_vm_over_shape_and_class(tmp_path):
    """A serial executor run with `--sampler.shape-by-class`: the actors' step clips reach the
    sampler with every value pair (none left out), Vm is fitted over the classes, and TensorBoard
    has each class's Vbar_c and the lowest class."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from learner import checkpoint
    from learner.train import train
    from sampler.shape_sampler import state_from_torch

    base = PRESETS["executor-tiny"][1]
    cfg = dataclasses.replace(
        base, runs_dir=str(tmp_path), quiet=True, mode="serial", max_iterations=2, total_env_steps=10**6,
        task=dataclasses.replace(base.task, executor=dataclasses.replace(base.task.executor, at_clip_end="stop")),
        sampler=dataclasses.replace(base.sampler, shape_by_class=True, k=5.0, p_mcmc=1, vm_fit_steps=4))
    assert train(cfg) == 0
    state = state_from_torch(checkpoint.load_latest(tmp_path / "executor-tiny" / "ckpt")[1]["sampler"])
    assert state["meta"]["version"] == 2 and state["meta"]["classes"]
    assert state["meta"]["vm"]["pairs_seen"] > 0 and any(state["meta"]["vm"]["class_seen"])
    tb = EventAccumulator(str(tmp_path / "executor-tiny" / "tb"), size_guidance={"scalars": 0})
    tb.Reload()
    tags = set(tb.Tags()["scalars"])
    assert "sampler/vm/class/root/locomotion/walk/vbar" in tags and "sampler/vm/lowest_vbar" in tags
    assert any(t.startswith("sampler/vm/lowest/") for t in tags)
    assert tb.Scalars("faults/value_pairs_lost")[-1].value == 0
