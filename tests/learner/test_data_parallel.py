"""Data-parallel PPO (`learner.data_parallel`): two real processes in a gloo group on 127.0.0.1
take the single learner's steps, stay equal to each other, and agree on the KL stop and on
skipping a minibatch whose loss is not finite on one of them only."""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
import tempfile

import numpy as np
import pytest
import torch

from common.policy import GaussianPolicy, PolicyConfig, ValueNet
from learner import data_parallel
from learner.bench.learner_update import random_batch
from learner.ppo import PPO, PPOConfig

OBS, ACT = 9, 3
CASES = {
    "plain": PPOConfig(epochs=3, minibatch=64, lr=1e-3),
    "kl stop and proximal anchor": PPOConfig(epochs=4, minibatch=64, lr=3e-3, kl_stop=0.002, proximal_anchor=True),
    "kl penalty, entropy, adaptive rate": PPOConfig(epochs=2, minibatch=32, lr=1e-3, kl_coef=0.2, entropy_coef=0.01,
                                                    lr_schedule="adaptive"),
}


def _ppo(cfg: PPOConfig) -> tuple[PPO, object]:
    torch.manual_seed(3)
    pcfg = PolicyConfig(hidden=(32, 32))
    ppo = PPO(GaussianPolicy(OBS, ACT, pcfg), ValueNet(OBS, pcfg), cfg)
    return ppo, random_batch(ppo.policy, 1024, 16, seed=4)


def _flat(ppo: PPO) -> np.ndarray:
    tensors = [*ppo.policy.state_dict().values(), *ppo.value.state_dict().values()]
    return torch.cat([t.detach().reshape(-1).double() for t in tensors]).numpy()


def _replica(rank: int, world: int, init_method: str, case: str, poison_rank: int, out) -> None:
    torch.set_num_threads(1)
    ppo, batch = _ppo(CASES[case])
    if rank == poison_rank:  # this replica's copy of a few actions is NaN: its slice's loss is not finite
        batch.actions[0, :8, 0] = float("nan")
    data_parallel.join(init_method, rank, world, torch.device("cpu"), timeout_s=60)
    try:
        sync = data_parallel.GradientSync(rank, world)
        gen = torch.Generator().manual_seed(7)
        metrics = [ppo.update(batch, gen, sync) for _ in range(2)]
        out.put((rank, _flat(ppo), metrics))
    finally:
        data_parallel.leave()


def _run_group(case: str, world: int = 2, poison_rank: int = -1) -> dict[int, tuple]:
    ctx = mp.get_context("spawn")
    out = ctx.Queue()
    init_method = data_parallel.rendezvous("127.0.0.1", tempfile.gettempdir())
    procs = [ctx.Process(target=_replica, args=(r, world, init_method, case, poison_rank, out)) for r in range(world)]
    for p in procs:
        p.start()
    try:
        results = {}
        for _ in range(world):
            rank, flat, metrics = out.get(timeout=120)
            results[rank] = (flat, metrics)
    finally:
        for p in procs:
            p.join(timeout=30)
            if p.is_alive():
                p.kill()
    assert all(p.exitcode == 0 for p in procs), [p.exitcode for p in procs]
    return results


@pytest.mark.parametrize("case", list(CASES))
def test_two_replicas_stay_equal_and_take_the_single_learners_steps(case, one_thread):
    results = _run_group(case)
    (flat0, m0), (flat1, m1) = results[0], results[1]
    assert np.abs(flat0 - flat1).max() <= 1e-6
    single, batch = _ppo(CASES[case])
    before = _flat(single)
    gen = torch.Generator().manual_seed(7)
    ms = [single.update(batch, gen) for _ in range(2)]
    moved = np.abs(_flat(single) - before).max()
    assert moved > 1e-3, "the updates moved nothing: the comparison below would prove nothing"
    # The same minibatches and steps; only the order of the floating-point sums differs.
    assert np.abs(flat0 - _flat(single)).max() < 1e-4 * max(1.0, moved)
    for a, b, c in zip(m0, m1, ms):
        assert a["minibatch_steps"] == b["minibatch_steps"] == c["minibatch_steps"]
        assert a["policy_steps"] == b["policy_steps"] == c["policy_steps"]
        assert a["kl"] == pytest.approx(b["kl"], rel=1e-6) and a["kl"] == pytest.approx(c["kl"], rel=1e-3)
        assert a["lr"] == b["lr"] == c["lr"]
    if CASES[case].kl_stop:
        assert ms[0]["policy_steps"] < ms[0]["minibatch_steps"], "the KL stop never fired: the case tests nothing"


def test_a_loss_not_finite_on_one_replica_skips_that_step_on_both(one_thread):
    results = _run_group("plain", poison_rank=1)
    (flat0, m0), (flat1, m1) = results[0], results[1]
    assert np.isfinite(flat0).all() and np.abs(flat0 - flat1).max() <= 1e-6
    # Minibatches whose rank-1 slice holds a NaN action are skipped by both replicas.
    assert m0[-1]["skipped_updates"] == m1[-1]["skipped_updates"] > 0
    assert m0[0]["minibatch_steps"] == m1[0]["minibatch_steps"] < 1024 // 64 * CASES["plain"].epochs


def test_the_config_refuses_replicas_it_cannot_split_a_minibatch_among():
    from learner.config import RunConfig

    with pytest.raises(ValueError, match="--ppo.minibatch 128 does not divide among --learner.replicas 3"):
        dataclasses.replace(RunConfig(mode="local"), learner=dataclasses.replace(RunConfig().learner, replicas=3))
    with pytest.raises(ValueError, match="needs Ray"):
        dataclasses.replace(RunConfig(mode="serial"), learner=dataclasses.replace(RunConfig().learner, replicas=2))


def _drifting_replica(rank: int, init_method: str, out) -> None:
    torch.set_num_threads(1)
    ppo, _ = _ppo(CASES["plain"])
    if rank == 1:  # as a node that computes differently would leave it
        with torch.no_grad():
            next(ppo.value.parameters()).add_(1e-3)
    data_parallel.join(init_method, rank, 2, torch.device("cpu"), timeout_s=60)
    try:
        tensors = [*ppo.policy.state_dict().values(), *ppo.value.state_dict().values()]
        try:
            data_parallel.GradientSync(rank, 2).check_equal(tensors)
            out.put((rank, "equal"))
        except RuntimeError as exc:
            out.put((rank, str(exc)))
    finally:
        data_parallel.leave()


def test_replicas_whose_copies_drifted_apart_stop_on_both_sides(tmp_path):
    ctx = mp.get_context("spawn")
    out = ctx.Queue()
    init_method = data_parallel.rendezvous("127.0.0.1", tmp_path)
    procs = [ctx.Process(target=_drifting_replica, args=(r, init_method, out)) for r in range(2)]
    for p in procs:
        p.start()
    results = dict(out.get(timeout=120) for _ in range(2))
    for p in procs:
        p.join(timeout=30)
    assert all("learner replicas diverged" in results[r] for r in range(2)), results
