"""PPO maths against plain reference implementations."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from common.policy import GaussianPolicy, ObsNormalizer, PolicyConfig, ValueNet, anneal_log_std
from learner.ppo import PPO, Batch, PPOConfig, gae, ppo_losses


def reference_gae(r, v, nv, term, trunc, gamma, lam):
    """The textbook loop over one stream, written independently of `gae`."""
    T = len(r)
    adv = np.zeros(T)
    next_adv = 0.0
    for t in reversed(range(T)):
        if term[t]:
            delta, next_adv = r[t] - v[t], 0.0
        elif trunc[t]:
            delta, next_adv = r[t] + gamma * nv[t] - v[t], 0.0
        else:
            delta = r[t] + gamma * nv[t] - v[t]
        adv[t] = delta + gamma * lam * next_adv
        next_adv = adv[t]
    return adv


def test_gae_matches_reference_loop_with_terminations_and_truncations():
    rng = np.random.default_rng(1)
    T, B = 40, 6
    r, v, nv = rng.normal(size=(3, T, B))
    term = rng.random((T, B)) < 0.1
    trunc = (rng.random((T, B)) < 0.1) & ~term
    adv, ret = gae(*(torch.as_tensor(x) for x in (r, v, nv, term, trunc)), gamma=0.95, lam=0.9)
    for b in range(B):
        ref = reference_gae(r[:, b], v[:, b], nv[:, b], term[:, b], trunc[:, b], 0.95, 0.9)
        np.testing.assert_allclose(adv[:, b].numpy(), ref, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(ret.numpy(), adv.numpy() + v)


def test_truncation_bootstraps_but_termination_does_not():
    one = lambda x: torch.tensor([[x]], dtype=torch.float64)  # noqa: E731
    kw = dict(rewards=one(1.0), values=one(0.0), next_values=one(10.0), gamma=0.5, lam=1.0)
    adv_term, _ = gae(terminated=torch.tensor([[True]]), truncated=torch.tensor([[False]]), **kw)
    adv_trunc, _ = gae(terminated=torch.tensor([[False]]), truncated=torch.tensor([[True]]), **kw)
    assert float(adv_term) == 1.0
    assert float(adv_trunc) == 6.0


def test_clipped_surrogate_stops_gradient_beyond_the_clip():
    cfg = PPOConfig(clip=0.2)
    mean = torch.zeros(1, 1, requires_grad=True)
    dist = torch.distributions.Normal(mean, torch.ones(1, 1))
    action = torch.zeros(1, 1)
    old_logp = dist.log_prob(action).sum(-1).detach() - 1.0  # ratio e^1 > 1.2
    losses = ppo_losses(dist, action, old_logp, torch.ones(1), torch.zeros(1), torch.zeros(1), cfg)
    losses["policy"].backward()
    assert mean.grad.abs().item() == 0.0
    assert losses["clip_frac"].item() == 1.0


def test_normalizer_matches_numpy_over_several_batches():
    rng = np.random.default_rng(2)
    data = [rng.normal(3.0, 2.0, size=(n, 4)) for n in (10, 200, 33)]
    norm = ObsNormalizer(4)
    for d in data:
        norm.update(torch.as_tensor(d))
    all_ = np.concatenate(data)
    np.testing.assert_allclose(norm.mean.numpy(), all_.mean(0), rtol=1e-10)
    np.testing.assert_allclose(norm.var.numpy(), all_.var(0), rtol=1e-10)


def test_normalizer_centres_but_does_not_amplify_a_dimension_that_never_varied():
    """A policy trained on one body sees its shape parameters constant; on another body they
    must arrive as small centred inputs, not as +-clip."""
    rng = np.random.default_rng(3)
    train = np.column_stack([rng.normal(0.0, 2.0, 500), np.full(500, 1.0)])
    norm = ObsNormalizer(2)
    norm.update(torch.as_tensor(train))
    out = norm(torch.tensor([[2.0, 1.1], [0.0, 1.0]], dtype=torch.float64))
    torch.testing.assert_close(out[:, 1], torch.tensor([0.1, 0.0], dtype=torch.float64))
    assert abs(out[0, 0].item() - (2.0 - norm.mean[0].item()) / np.sqrt(norm.var[0].item())) < 1e-6


def test_update_reduces_loss_on_a_fixed_batch_and_skips_nan():
    torch.manual_seed(0)
    cfg = PolicyConfig(hidden=(16, 16))
    policy, value = GaussianPolicy(3, 2, cfg), ValueNet(3, cfg)
    ppo = PPO(policy, value, PPOConfig(minibatch=32, epochs=4, lr=1e-2))
    T, B = 16, 8
    obs = torch.randn(T, B, 3)
    with torch.no_grad():
        dist = policy.distribution(obs)
        actions = dist.sample()
        logp = dist.log_prob(actions).sum(-1)
    batch = Batch(obs, torch.randn(T, B, 3), actions, logp, torch.ones(T, B), torch.zeros(T, B, dtype=torch.bool),
                  torch.zeros(T, B, dtype=torch.bool))
    first = ppo.update(batch)["value"]
    for _ in range(5):
        last = ppo.update(batch)["value"]
    assert last < first
    bad = Batch(obs, obs, actions, logp, torch.full((T, B), float("nan")), batch.terminated, batch.truncated)
    before = [p.clone() for p in policy.parameters()]
    ppo.update(bad)
    assert ppo.skipped_updates > 0
    assert all(torch.equal(a, b) for a, b in zip(before, policy.parameters()))


def _random_batch(policy: GaussianPolicy, T: int = 16, B: int = 8) -> Batch:
    obs = torch.randn(T, B, policy.obs_dim)
    with torch.no_grad():
        dist = policy.distribution(obs)
        actions = dist.sample()
        logp = dist.log_prob(actions).sum(-1)
    no = torch.zeros(T, B, dtype=torch.bool)
    return Batch(obs, torch.randn(T, B, policy.obs_dim), actions, logp, torch.randn(T, B), no, no)


def test_kl_stop_bounds_how_far_one_update_moves_the_policy():
    """With a learning rate large enough to wreck the policy, kl_stop stops the policy early,
    while the value network trains on for every epoch."""
    runs, values = {}, {}
    for kl_stop in (0.0, 0.02):
        torch.manual_seed(0)
        cfg = PolicyConfig(hidden=(16, 16))
        policy, value = GaussianPolicy(3, 2, cfg), ValueNet(3, cfg)
        ppo = PPO(policy, value, PPOConfig(minibatch=16, epochs=10, lr=3e-2, kl_stop=kl_stop))
        batch = _random_batch(policy)
        runs[kl_stop] = ppo.update(batch)
        values[kl_stop] = value(policy.normalizer(batch.obs)).detach()
    assert runs[0.0]["minibatch_steps"] == runs[0.0]["policy_steps"] == 80
    assert runs[0.02]["minibatch_steps"] == 80
    assert runs[0.02]["policy_steps"] < 80
    assert runs[0.02]["kl"] < runs[0.0]["kl"]
    # The value net saw the same 80 steps either way (its loss does not depend on the policy).
    torch.testing.assert_close(values[0.02], values[0.0])


def test_proximal_anchor_measures_only_this_updates_movement_on_stale_data():
    """Actors' data from an older policy version: with the behaviour anchor the update starts
    clipped and with KL > 0 before any step (lr 0: the policy never moves); with the proximal
    anchor (decoupled PPO) both are 0 until the update moves the policy."""
    torch.manual_seed(0)
    cfg = PolicyConfig(hidden=(16, 16))
    policy, value = GaussianPolicy(3, 2, cfg), ValueNet(3, cfg)
    batch = _random_batch(policy)
    with torch.no_grad():  # the learner has moved on since the actors acted
        for p in policy.mean_net.parameters():
            p.add_(0.3 * torch.randn_like(p))
    out = {}
    for anchor in (False, True):
        ppo = PPO(policy, value, PPOConfig(minibatch=16, epochs=1, lr=0.0, proximal_anchor=anchor))
        out[anchor] = ppo.update(batch)
    assert out[False]["clip_frac"] > 0.1 and out[False]["kl"] > 0.01
    assert out[True]["clip_frac"] == 0.0 and out[True]["kl"] == pytest.approx(0.0, abs=1e-7)


def test_proximal_anchor_is_plain_ppo_on_fresh_data():
    """Data from the current policy: the weights are 1 and the anchor is the behaviour policy,
    so both variants take the same steps."""
    params = {}
    for anchor in (False, True):
        torch.manual_seed(0)
        cfg = PolicyConfig(hidden=(16, 16))
        policy, value = GaussianPolicy(3, 2, cfg), ValueNet(3, cfg)
        batch = _random_batch(policy)
        PPO(policy, value, PPOConfig(minibatch=16, epochs=3, lr=1e-3, proximal_anchor=anchor)).update(
            batch, torch.Generator().manual_seed(1))
        params[anchor] = [p.detach().clone() for p in policy.parameters()]
    for a, b in zip(params[False], params[True]):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_variance_controller_anneals_the_mean_log_std_and_keeps_the_spread():
    """UniCon's policy variance controller: mean log sigma moves linearly, all components alike."""
    cfg = PolicyConfig(hidden=(8,), init_log_std=-1.0, final_log_std=-2.0, log_std_anneal_steps=1000, learn_log_std=False)
    policy = GaussianPolicy(3, 4, cfg)
    assert not policy.log_std.requires_grad
    with torch.no_grad():
        policy.log_std.add_(torch.tensor([0.1, -0.1, 0.2, -0.2]))
    spread = policy.log_std - policy.log_std.mean()
    anneal_log_std(policy, cfg, 250)
    assert policy.log_std.mean().item() == pytest.approx(-1.25)
    torch.testing.assert_close(policy.log_std - policy.log_std.mean(), spread)
    anneal_log_std(policy, cfg, 5000)
    assert policy.log_std.mean().item() == pytest.approx(-2.0)


def test_a_fixed_log_std_does_not_move_in_an_update():
    torch.manual_seed(0)
    cfg = PolicyConfig(hidden=(16,), learn_log_std=False)
    policy, value = GaussianPolicy(3, 2, cfg), ValueNet(3, cfg)
    before = policy.log_std.detach().clone()
    PPO(policy, value, PPOConfig(minibatch=16, epochs=2, lr=1e-2)).update(_random_batch(policy))
    assert torch.equal(policy.log_std.detach(), before)


@pytest.mark.parametrize("schedule, expected", [("constant", 1e-4), ("linear", 1e-4), ("adaptive", "saved")])
def test_resumed_step_size_follows_the_config_unless_the_schedule_adapts_it(schedule, expected):
    """`--ppo.lr` on a resumed run takes effect; only the adaptive schedule's rate is state."""
    cfg = PolicyConfig(hidden=(8,))
    policy, value = GaussianPolicy(3, 2, cfg), ValueNet(3, cfg)
    saved = PPO(policy, value, PPOConfig(lr=7e-4, lr_schedule=schedule))
    saved.update(_random_batch(policy))
    resumed = PPO(policy, value, PPOConfig(lr=1e-4, lr_schedule=schedule))
    resumed.optimizer.load_state_dict(saved.optimizer.state_dict())
    resumed.restore_lr(saved.lr)
    expected = saved.lr if expected == "saved" else expected
    assert saved.lr != pytest.approx(1e-4)
    assert resumed.lr == pytest.approx(expected)
    assert all(g["lr"] == pytest.approx(expected) for g in resumed.optimizer.param_groups)


def _twin_updates(ppo_cfg: PPOConfig, policy_cfg: PolicyConfig, obs_dim: int, act_dim: int, T: int, B: int, updates: int = 1):
    """The same networks, optimizer state and data through `reference_update` and `PPO.update`."""
    import copy

    from learner.ppo_reference import reference_update

    torch.manual_seed(0)
    policy, value = GaussianPolicy(obs_dim, act_dim, policy_cfg), ValueNet(obs_dim, policy_cfg)
    g = torch.Generator().manual_seed(5)
    obs = 3.0 * torch.randn(T, B, obs_dim, generator=g) + torch.randn(obs_dim, generator=g)
    with torch.no_grad():
        dist = policy.distribution(obs)
        actions = dist.mean + dist.stddev * torch.randn(dist.mean.shape, generator=g)
        logp = dist.log_prob(actions).sum(-1)
    terminated = torch.rand(T, B, generator=g) < 0.05
    truncated = (torch.rand(T, B, generator=g) < 0.02) & ~terminated
    batch = Batch(obs, 3.0 * torch.randn(T, B, obs_dim, generator=g), actions, logp - 0.05 * torch.rand(T, B, generator=g),
                  5 * torch.rand(T, B, generator=g), terminated, truncated)
    ref, new = PPO(policy, value, ppo_cfg), None
    new = copy.deepcopy(ref)
    start = [p.detach().clone() for p in [*ref.policy.parameters(), *ref.value.parameters()]]
    for i in range(updates):
        m_ref = reference_update(ref, batch, torch.Generator().manual_seed(10 + i))
        m_new = new.update(batch, torch.Generator().manual_seed(10 + i))
    return ref, new, m_ref, m_new, start


_SAME_MATHS_CASES = {
    "lower_biped": (PPOConfig(epochs=10, minibatch=128, lr=1e-4, kl_stop=0.1), PolicyConfig(hidden=(128, 128, 128)), 164, 17, 32, 128),
    "executor": (PPOConfig(epochs=5, minibatch=512, lr=2e-4, kl_coef=0.2, kl_stop=0.1),
                 PolicyConfig(hidden=(64, 64, 64), init_log_std=-1.0, learn_log_std=False), 60, 28, 32, 64),
    "kl_stop_fires": (PPOConfig(epochs=6, minibatch=32, lr=3e-2, kl_stop=0.02), PolicyConfig(hidden=(32, 32)), 9, 3, 16, 16),
    "entropy_anchor_adaptive": (PPOConfig(epochs=3, minibatch=48, lr=1e-3, entropy_coef=0.01, kl_coef=0.1, proximal_anchor=True,
                                          lr_schedule="adaptive", normalize_advantages=False, vf_coef=1.0),
                                PolicyConfig(hidden=(32, 32), activation="tanh"), 9, 3, 16, 16),
}




@pytest.mark.parametrize("case", list(_SAME_MATHS_CASES))
def test_update_takes_the_reference_loops_steps(case, one_thread):
    """`PPO.update` computes its minibatch steps with fewer operations than the textbook loop
    (`learner.ppo_reference`); after two updates on the same data from the same state, the
    parameters, Adam's moments, the normalizer and the metrics agree to float rounding (today
    bit for bit; 1e-5 leaves room for a kernel that rounds differently, not for other maths:
    a changed loss, order or step moves them by 1e-3 or more, see `moved`)."""
    ppo_cfg, policy_cfg, obs_dim, act_dim, T, B = _SAME_MATHS_CASES[case]
    ref, new, m_ref, m_new, start = _twin_updates(ppo_cfg, policy_cfg, obs_dim, act_dim, T, B, updates=2)
    params_ref = [*ref.policy.parameters(), *ref.value.parameters()]
    params_new = [*new.policy.parameters(), *new.value.parameters()]
    moved = max(float((p.detach() - s).abs().max()) for p, s in zip(params_ref, start))
    assert moved > 1e-3  # the updates did something to compare
    for a, b in zip(params_ref, params_new):
        torch.testing.assert_close(b, a, rtol=0, atol=1e-5)
    for a, b in zip(ref.policy.buffers(), new.policy.buffers()):
        torch.testing.assert_close(b, a, rtol=0, atol=0)
    for p_ref, p_new in zip(params_ref, params_new):
        s_ref, s_new = ref.optimizer.state.get(p_ref, {}), new.optimizer.state.get(p_new, {})
        assert s_ref.keys() == s_new.keys()
        for k in s_ref:
            torch.testing.assert_close(s_new[k], s_ref[k], rtol=1e-5, atol=1e-8)
    assert m_new.keys() == m_ref.keys()
    for k in m_ref:
        assert m_new[k] == pytest.approx(m_ref[k], rel=1e-4, abs=1e-6, nan_ok=True), k
    assert new.lr == ref.lr
    if case == "kl_stop_fires":
        assert 0 < m_new["policy_steps"] < m_new["minibatch_steps"]


def test_update_skips_non_finite_minibatches_like_the_reference(one_thread):
    cfg = PPOConfig(epochs=2, minibatch=32)
    ref, new, m_ref, m_new, _ = _twin_updates(cfg, PolicyConfig(hidden=(16, 16)), 5, 2, 16, 8)
    from learner.ppo_reference import reference_update

    T, B = 16, 8
    bad = Batch(torch.randn(T, B, 5), torch.randn(T, B, 5), torch.zeros(T, B, 2), torch.zeros(T, B),
                torch.full((T, B), float("nan")), torch.zeros(T, B, dtype=torch.bool), torch.zeros(T, B, dtype=torch.bool))
    before = [p.detach().clone() for p in new.policy.parameters()]
    m_ref, m_new = reference_update(ref, bad), new.update(bad)
    assert new.skipped_updates == ref.skipped_updates == 8
    assert m_new.keys() == m_ref.keys() and m_new["minibatch_steps"] == 0
    assert all(torch.equal(a, b) for a, b in zip(before, new.policy.parameters()))


# --- issue 23: PPO as intended --------------------------------------------------------------


def _far_batch(policy: GaussianPolicy, T: int = 16, B: int = 8, reward_scale: float = 1.0) -> Batch:
    """Observations far from a fresh normalizer's (0, 1), actions and log-probabilities from
    `policy` as it is (the actors' policy, normalizer included)."""
    obs = 5.0 + 3.0 * torch.randn(T, B, 3)
    with torch.no_grad():
        dist = policy.distribution(obs.reshape(T * B, 3))
        actions = dist.sample()
        logp = dist.log_prob(actions).sum(-1)
    return Batch(obs=obs, next_obs=obs + 0.1, actions=actions.reshape(T, B, -1), logp=logp.reshape(T, B),
                 rewards=reward_scale * (1.0 + torch.rand(T, B)), terminated=torch.zeros(T, B, dtype=torch.bool),
                 truncated=torch.zeros(T, B, dtype=torch.bool))


def test_the_first_minibatch_sees_the_policy_the_actors_ran() -> None:
    """lr 0: the policy never moves, so every ratio is 1 and the KL 0, even though this batch
    moves the observation statistics a long way (they move after the epochs)."""
    torch.manual_seed(0)
    cfg = PolicyConfig(hidden=(16, 16))
    policy, value = GaussianPolicy(3, 2, cfg), ValueNet(3, cfg)
    batch = _far_batch(policy)
    before = policy.normalizer.mean.clone()
    out = PPO(policy, value, PPOConfig(minibatch=32, epochs=2, lr=0.0)).update(batch)
    assert out["kl"] == pytest.approx(0.0, abs=1e-7) and out["clip_frac"] == 0.0
    assert (policy.normalizer.mean - before).abs().max() > 1.0  # and the statistics did move, afterwards


def test_the_reported_kl_is_the_moving_policys(monkeypatch) -> None:
    """With a KL stop, the KL reported (and fed to the adaptive rate) averages the minibatches
    measured while the policy moved, up to the one that stopped it, not the frozen rest."""
    import learner.ppo as ppo_module

    torch.manual_seed(0)
    cfg = PolicyConfig(hidden=(16, 16))
    policy, value = GaussianPolicy(3, 2, cfg), ValueNet(3, cfg)
    batch = _far_batch(policy)
    seen = []
    real = ppo_module._policy_losses

    def recording(*args, **kw):
        out = real(*args, **kw)
        seen.append(float(out[2]))
        return out

    monkeypatch.setattr(ppo_module, "_policy_losses", recording)
    out = PPO(policy, value, PPOConfig(minibatch=16, epochs=4, lr=3e-2, kl_stop=1e-4)).update(batch)
    moving = int(out["policy_steps"]) + 1  # the steps taken and the minibatch that stopped them
    assert 1 < moving < len(seen), "the stop should fire within the update"
    assert out["kl"] == pytest.approx(np.mean(seen[:moving]), rel=1e-5)
    assert out["kl"] < np.mean(seen), "the frozen policy's minibatches must not enter the reported KL"


def test_value_statistics_keep_every_value_and_standardize_the_targets() -> None:
    torch.manual_seed(0)
    cfg = PolicyConfig(hidden=(16, 16))
    value = ValueNet(3, cfg)
    obs = torch.randn(64, 3)
    with torch.no_grad():
        before = value(obs).clone()
    for scale in (100.0, 300.0):
        value.update_target_stats(scale + 10.0 * torch.randn(512))
        with torch.no_grad():
            torch.testing.assert_close(value(obs), before, rtol=1e-4, atol=1e-3)
    assert float(value.target_std) > 5.0 and float(value.target_mean) > 100.0


@pytest.mark.parametrize("scale", [100.0])
def test_standardized_targets_bring_the_value_gradient_to_the_policys_scale(scale: float) -> None:
    """Returns of ~100 x (1/(1-gamma)): with raw targets the value gradient dwarfs the policy's;
    with standardized ones it is of the same order."""
    norms = {}
    for on in (False, True):
        torch.manual_seed(0)
        cfg = PolicyConfig(hidden=(16, 16))
        policy, value = GaussianPolicy(3, 2, cfg), ValueNet(3, cfg)
        batch = _far_batch(policy, reward_scale=scale)
        out = PPO(policy, value, PPOConfig(minibatch=32, epochs=1, lr=1e-3, value_normalization=on)).update(batch)
        norms[on] = out["value_grad_norm"] / max(out["grad_norm"], 1e-8)
    assert norms[False] > 100.0, norms
    assert norms[True] < norms[False] / 30.0, norms
