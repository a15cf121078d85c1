"""Content checked before it counts (issue 54, item 1), over real ZeroMQ on 127.0.0.1: an unroll
no honest actor of the task could send (observations of 3e38, rewards of 1e30, a parameter
outside the sampler's box, divergences past its terminated steps, impossible returns and
lengths, clips the task lacks, more sampler outages than draws) is dropped whole and counted by
reason, while the clean unrolls of the same iteration train a real learner and its value report
reaches a real sampler."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import zmq

from actors.draws import DrawCache
from actors.rollout import RolloutWorker
from common import sockets, wire
from common.policy import policy_tensors
from common.tasks.registry import task_bounds, task_space
from learner import checkpoint
from learner.learner import Learner
from learner.presets import PRESETS
from learner.sampler_handle import SamplerHandle
from learner.train import Run, train
from learner.transport import LearnerTransport
from learner.unroll_bounds import REASONS, UnrollBounds

CFG = PRESETS["reach-tiny"][1]
T, N = CFG.actors.unroll_length, CFG.actors.envs_per_actor
OBS, ACT, SPACE = 12, 2, task_space(CFG.task)


def clean_unroll(seq: int, actor_id: int = 0, seed: int = 0) -> wire.UnrollMsg:
    """A reach unroll an honest actor could send: small observations, rewards in the bell's
    range, one target per environment inside the box, and two episodes of environment 1 (one
    begun in an earlier unroll, one wholly inside this one) whose lengths and returns add up."""
    rng = np.random.default_rng(seed)
    rewards = rng.uniform(0.0, 0.8, (T, N)).astype(np.float32)
    terminated, truncated = np.zeros((T, N), bool), np.zeros((T, N), bool)
    truncated[3, 1] = terminated[9, 1] = True
    params = np.broadcast_to(SPACE.uniform(rng, N).astype(np.float32), (T, N, SPACE.dim)).copy()
    return wire.UnrollMsg(
        actor_id=actor_id, seq=seq, policy_version=0,
        obs=rng.normal(0, 1, (T, N, OBS)).astype(np.float32), next_obs=rng.normal(0, 1, (T, N, OBS)).astype(np.float32),
        actions=rng.normal(0, 1, (T, N, ACT)).astype(np.float32), logp=np.zeros((T, N), np.float32),
        rewards=rewards, terminated=terminated, truncated=truncated, params=params,
        episode_returns=[float(rewards[:4, 1].sum(dtype=np.float64)) + 2.5, float(rewards[4:10, 1].sum(dtype=np.float64))],
        episode_lengths=[4 + 10, 6],  # the first began 10 steps before this unroll and earned 2.5 there
    )


def _poisoned(seq: int) -> list[tuple[str, wire.UnrollMsg]]:
    """(reason, unroll): each wrong in one way, as measured on main or as a peer could lie."""
    u = clean_unroll(seq)
    obs = u.obs.copy()
    obs[5, 2, 7] = 3e38
    params = u.params.copy()
    params[0, 0, 1] = 0.9  # target_radius: the box ends at 0.216 m
    return [
        ("obs", dataclasses.replace(u, obs=obs)),
        ("reward", dataclasses.replace(u, rewards=np.full((T, N), 1e30, np.float32))),
        ("params", dataclasses.replace(u, params=params)),
        ("divergences", dataclasses.replace(u, divergences=2**53)),
        ("returns", dataclasses.replace(u, episode_returns=[u.episode_returns[0], 1e9])),
        ("episodes", dataclasses.replace(u, episode_lengths=[2**40, 6])),  # longer than the 50-step horizon
        ("episodes", dataclasses.replace(u, episode_lengths=[14, 9])),  # ran 6 steps here, not 9
        ("episodes", dataclasses.replace(u, episode_returns=[*u.episode_returns, 1.0], episode_lengths=[14, 6, 1])),
        ("segments", dataclasses.replace(u, segment_clips=["walk"], segment_tracked=[1])),  # reach has no clips
        ("outages", dataclasses.replace(u, sampler_outages=2**40)),
    ]


def _transport() -> LearnerTransport:
    return LearnerTransport("127.0.0.1", OBS, ACT, SPACE.dim, unroll_length=T, envs_per_actor=N, num_actors=2,
                            bounds=UnrollBounds.for_task(CFG.task))


def _push(t: LearnerTransport) -> zmq.Socket:
    push = zmq.Context.instance().socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 1000)
    push.connect(t.endpoints["unrolls"])
    return push


def _receive(t: LearnerTransport, count: int, rounds: int = 100) -> list[wire.UnrollMsg]:
    got: list[wire.UnrollMsg] = []
    for _ in range(rounds):
        got += t.receive(50, 0, 5)
        if len(got) + t.rejected() >= count:
            break
    return got


def test_the_reach_bounds_are_what_its_reward_can_be() -> None:
    b = task_bounds(CFG.task)
    assert (b.reward_min, b.reward_max, b.obs_max_abs, b.episode_steps) == (-0.02, 1.0, 1e3, 50)


@pytest.mark.parametrize("preset", ["reach", "lower_biped", "executor"])
def test_honest_actors_of_every_family_stay_inside_their_bounds(preset: str) -> None:
    """Real rollout workers (an untrained policy: falls, terminations, divergences are likely)
    send nothing their task's bounds refuse, episodes that began in an earlier unroll included."""
    cfg = PRESETS[preset][1]
    worker = RolloutWorker(0, cfg.task, cfg.policy, dataclasses.replace(cfg.actors, envs_per_actor=2, unroll_length=48),
                           DrawCache(None, task_space(cfg.task), 32))
    worker.set_weights(wire.WeightsMsg(policy_version=0, tensors=policy_tensors(worker.policy)))
    bounds = UnrollBounds.for_task(cfg.task)
    ended = 0
    for _ in range(3):
        u = worker.collect()
        bounds.check(u)
        ended += len(u.episode_returns)
    assert ended > 0 or preset == "lower_biped"


def test_a_clean_unroll_passes_and_each_poisoned_one_names_its_value() -> None:
    bounds = UnrollBounds.for_task(CFG.task)
    bounds.check(clean_unroll(0))
    for reason, u in _poisoned(1):
        with pytest.raises(wire.WireError) as exc:
            bounds.check(u)
        assert exc.value.kind == f"bounds_{reason}", (reason, str(exc.value))
        assert "allowed" in str(exc.value) and "\n" not in str(exc.value)
    assert {reason for reason, _ in _poisoned(1)} == set(REASONS)


def test_poisoned_unrolls_are_dropped_whole_and_the_clean_ones_train_and_reach_the_sampler() -> None:
    """Clean and poisoned unrolls of one iteration arrive together: the poisoned ones are counted
    by reason and never reach the learner; the clean ones train it, its normalizer and counters
    stay sane, and the value report built from them is stored by the sampler, which refuses one
    that carries the poisoned unroll's parameter."""
    t = _transport()
    push = _push(t)
    poisoned = _poisoned(1)
    handle = SamplerHandle.start(CFG.sampler, SPACE, [], None)
    try:
        push.send_multipart(wire.encode(clean_unroll(0, seed=1)))
        for k, (_, u) in enumerate(poisoned):
            push.send_multipart(wire.encode(dataclasses.replace(u, seq=1 + k)))
        push.send_multipart(wire.encode(clean_unroll(len(poisoned) + 1, seed=2)))
        for seq in range(3):
            push.send_multipart(wire.encode(clean_unroll(seq, actor_id=1, seed=3 + seq)))
        got = _receive(t, 5 + len(poisoned))
        assert [(u.actor_id, u.seq) for u in got] == [(0, 0), (0, len(poisoned) + 1), (1, 0), (1, 1), (1, 2)]
        expected = {f"rejected/bounds_{reason}": sum(r == reason for r, _ in poisoned) for reason in REASONS}
        assert {k: v for k, v in t.counters.items() if k.startswith("rejected/")} == expected
        assert t.counters["seq_gap_unrolls"] == 0  # a dropped unroll arrived: it is no lost one
        assert t.counters["unrolls_received"] == 5 and sum(t.received.values()) == 5
        assert sum(t.sampler_outages.values()) == 0

        learner = Learner(dataclasses.replace(CFG, seed=0))
        metrics = learner.update(got)
        assert np.isfinite(metrics["losses/value"]) and learner.counters["divergences"] == 0
        assert learner.episodes == 2 * len(got)
        assert float(learner.policy.normalizer.mean.abs().max()) < 5 and float(learner.policy.normalizer.var.max()) < 5
        assert float(learner.value.target_std) < 100
        learner.policy.normalizer.check()

        params, values = learner.value_pairs(got, 256)
        stats = handle.report_and_tick(params, values, learner.iteration)
        assert stats["sampler/vm/pairs_seen"] == 256 and stats["sampler/learner_call_failures"] == 0
        bad = params.copy()
        bad[0] = poisoned[2][1].params[0, 0]
        with pytest.raises(wire.WireError, match="target_radius"):  # what the sampler did on main
            handle.client.report(bad, values)
    finally:
        handle.stop()
        push.close()
        t.close()


def test_a_poisoned_insider_in_a_real_run_is_counted_and_changes_nothing_that_learns(tmp_path) -> None:
    """A serial reach run (real actors, collector, learner and sampler; CURVE on) in which a peer
    holding actor 1's key sends, after each of the first iterations, unrolls of 3e38
    observations, 1e30 rewards, a target outside the box and 2^53 divergences under actor 1's
    next numbers. Every one is counted by reason; the run's statistics, counters and checkpoints
    stay those of the honest actors, and every iteration's value report is stored."""
    cfg = dataclasses.replace(CFG, runs_dir=str(tmp_path), quiet=True, mode="serial", max_iterations=4,
                              total_env_steps=10**6, checkpoint_every=1, vm_plot_every=0)
    seen: dict = {"pairs": []}

    def hook(run: Run, metrics: dict) -> None:
        seen["run"] = run
        seen["pairs"].append(metrics["sampler/vm/pairs_seen"])
        if run.learner.iteration <= 2:
            insider = sockets.connect_unroll_push(run.transport.endpoints["unrolls"], run.keys.for_actor(1))
            start = run.transport.last_seq.get(1, -1) + 1
            for k, (_, u) in enumerate(_poisoned(0)[:4]):
                insider.send_multipart(wire.encode(dataclasses.replace(u, actor_id=1, seq=start + k,
                                                                       policy_version=run.learner.policy_version)))
            insider.close(linger=2000)

    assert train(cfg, on_iteration=hook) == 0
    run = seen["run"]
    c = run.transport.counters
    for reason in ("obs", "reward", "params", "divergences"):
        assert c[f"rejected/bounds_{reason}"] >= 1, dict(c)
    assert run.learner.counters["divergences"] < 10 and c["seq_gap_unrolls"] == 0
    per_iteration = min(cfg.value_pairs_per_iteration, cfg.steps_per_iteration)  # a sample of the batch
    assert seen["pairs"] == [per_iteration * (i + 1) for i in range(4)]
    state = checkpoint.load_latest(tmp_path / cfg.name / "ckpt")[1]
    mean, var = state["policy"]["normalizer.mean"], state["policy"]["normalizer.var"]
    assert float(mean.abs().max()) < 10 and float(var.max()) < 100
    assert state["counters"]["divergences"] < 10
