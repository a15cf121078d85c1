"""`reference_update`: `PPO.update` as first written, kept as its specification.

One minibatch step here is the textbook sequence: gather the minibatch, normalize its
observations (once for the policy, once for the value net), build a `torch.distributions.Normal`,
`ppo_losses`, backward, `clip_grad_norm_` on each network, Adam. `PPO.update` computes the same
losses, gradients and Adam steps with fewer, larger operations; `tests/learner/test_ppo.py` holds
the two to the same parameters after an update, and `morphmimic bench learner` times both on
the same data. Not used in training. Issue 23's corrections are in both: the observation
normalizer moves after the epochs, the reported KL is that of the minibatches that measured the
moving policy, and the value net learns standardized returns.
"""

from __future__ import annotations

import torch
from torch import nn

from learner.ppo import PPO, Batch, _explained_variance, gae, ppo_losses


def reference_update(ppo: PPO, batch: Batch, generator: torch.Generator | None = None) -> dict[str, float]:
    """What `ppo.update(batch, generator)` computes, the straightforward way (same random
    minibatch order for the same generator state)."""
    self, cfg = ppo, ppo.cfg
    values = self.values_of(batch.obs)
    next_values = self.values_of(batch.next_obs)
    adv, returns = gae(batch.rewards, values, next_values, batch.terminated, batch.truncated, cfg.gamma, cfg.gae_lambda)

    flat = lambda x: x.reshape(-1, *x.shape[2:])  # noqa: E731
    obs, actions, old_logp = flat(batch.obs), flat(batch.actions), flat(batch.logp)
    adv, returns = flat(adv), flat(returns)
    if cfg.value_normalization:
        self.value.update_target_stats(returns)
    targets = self.value.standardize(returns)
    n = obs.shape[0]
    weights = None
    if cfg.proximal_anchor:
        behaviour_logp = old_logp
        old_logp = self.log_prob(obs, actions)
        weights = (old_logp - behaviour_logp).exp().clamp(max=cfg.behaviour_weight_max)
    sums: dict[str, float] = {}
    steps = policy_steps = 0
    policy_active = True
    for _ in range(cfg.epochs):
        order = torch.randperm(n, generator=generator)
        for start in range(0, n - cfg.minibatch + 1, cfg.minibatch):
            idx = order[start : start + cfg.minibatch]
            a = adv[idx]
            if cfg.normalize_advantages:
                a = (a - a.mean()) / (a.std() + 1e-8)
            dist = self.policy.distribution(obs[idx])
            v = self.value.standardized(self.policy.normalizer(obs[idx]))
            losses = ppo_losses(dist, actions[idx], old_logp[idx], a, v, targets[idx], cfg,
                                None if weights is None else weights[idx])
            if not torch.isfinite(losses["total"]):
                self.skipped_updates += 1
                continue
            measured_moving = policy_active
            if policy_active and cfg.kl_stop > 0 and policy_steps and losses["kl"].item() > cfg.kl_stop:
                policy_active = False
            self.optimizer.zero_grad(set_to_none=True)
            (losses["total"] if policy_active else cfg.vf_coef * losses["value"]).backward()
            grad_norm = nn.utils.clip_grad_norm_(list(self.policy.parameters()), cfg.max_grad_norm)
            value_grad_norm = nn.utils.clip_grad_norm_(list(self.value.parameters()), cfg.max_grad_norm)
            self.optimizer.step()
            for k, v_ in losses.items():
                sums[k] = sums.get(k, 0.0) + v_.item()
            sums["grad_norm"] = sums.get("grad_norm", 0.0) + float(grad_norm)
            sums["value_grad_norm"] = sums.get("value_grad_norm", 0.0) + float(value_grad_norm)
            if measured_moving:
                sums["kl_moving"] = sums.get("kl_moving", 0.0) + losses["kl"].item()
                sums["moving"] = sums.get("moving", 0.0) + 1.0
            steps += 1
            policy_steps += policy_active
    self.policy.normalizer.update(batch.obs.reshape(-1, batch.obs.shape[-1]))
    kl_moving, moving = sums.pop("kl_moving", 0.0), sums.pop("moving", 0.0)
    metrics = {k: v / max(steps, 1) for k, v in sums.items()}
    if steps:
        metrics["kl"] = kl_moving / max(moving, 1.0)
    if cfg.lr_schedule == "adaptive" and steps:
        kl = metrics["kl"]
        if kl > 2.0 * cfg.kl_target:
            self.lr = max(self.lr / 1.5, 1e-6)
        elif kl < 0.5 * cfg.kl_target:
            self.lr = min(self.lr * 1.5, 1e-2)
        self._apply_lr()
    metrics.update(
        lr=self.lr,
        explained_variance=_explained_variance(flat(values), returns),
        value_target_std=float(self.value.target_std),
        skipped_updates=float(self.skipped_updates),
        log_std=self.policy.log_std.detach().mean().item(),
        minibatch_steps=float(steps),
        policy_steps=float(policy_steps),
    )
    return metrics
