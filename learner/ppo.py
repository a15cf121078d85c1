"""Proximal Policy Optimization (Schulman et al. 2017) as pure torch code.

Nothing here knows about sockets, Ray or MuJoCo: `gae` and `ppo_losses` are functions of
tensors, and `PPO.update` takes a `Batch` of time-major `[T, B]` tensors.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import nn

from common.config_limits import Limit, above, at_least, between, check_limits, validated
from common.policy import GaussianPolicy, ValueNet
from learner.data_parallel import GradientSync


@dataclass(frozen=True)
@validated
class PPOConfig:
    gamma: float = 0.95
    """Discount (Won & Lee 2019 use 0.95)."""
    gae_lambda: float = 0.95
    """GAE lambda (Won & Lee 2019: 0.95)."""
    clip: float = 0.2
    """Clipped-surrogate epsilon."""
    epochs: int = 10
    """Passes over each batch."""
    minibatch: int = 128
    """Transitions per gradient step (Won & Lee 2019: 128)."""
    lr: float = 3e-4
    """Adam learning rate at the start of training."""
    lr_schedule: str = "constant"
    """constant | linear (to 0 at the step budget) | adaptive (scaled to keep KL near kl_target)."""
    vf_coef: float = 0.5
    """Weight of the value loss."""
    entropy_coef: float = 0.0
    """Weight of the entropy bonus."""
    kl_coef: float = 0.0
    """Weight of the KL(old || new) penalty (UniCon 2020 eq. 7); 0 turns it off."""
    kl_target: float = 0.01
    """Target KL per update for the adaptive learning rate."""
    kl_stop: float = 0.0
    """Stop moving the policy for the rest of this update once one minibatch's KL(old || new)
    exceeds this (the `1.5 * target_kl` early stop of Spinning Up and Stable-Baselines3); the
    value network keeps training for all epochs, as in Spinning Up's separate value iterations.
    0 turns it off. It bounds how far one batch can move the policy, whatever the learning rate."""
    max_grad_norm: float = 0.5
    """Gradient-norm clip, applied to the policy's and the value net's gradients separately."""
    normalize_advantages: bool = True
    """Standardize advantages per minibatch."""
    proximal_anchor: bool = False
    """Decoupled PPO (Hilton et al. 2021, "Batch size-invariance for policy optimization"): clip
    the ratio and measure the KL against the policy as it is when the update starts (the
    proximal policy), not against the actors' behaviour policy, and weight each sample by
    pi_prox / pi_behaviour (capped at `behaviour_weight_max`). Actors lag the learner by up to
    `max_policy_lag` versions, so with the behaviour anchor part of each update's clip range and
    KL budget is spent before it starts (clip fraction about 0.5 in the lower-biped runs)."""
    behaviour_weight_max: float = 2.0
    """Cap of the importance weight pi_prox / pi_behaviour with `proximal_anchor` (V-trace style)."""
    value_normalization: bool = True
    """Train the value net on standardized returns (running statistics, PopArt's output-preserving
    rescale: `common.policy.ValueNet`). Off: raw returns, whose gradient was about 100 times the
    policy's with returns of about 100 (for the comparison)."""

    FLAG_PREFIX: ClassVar[str] = "ppo"
    LIMITS: ClassVar[dict[str, Limit]] = {
        "gamma": between(0, 1, lo_open=True), "gae_lambda": between(0, 1), "clip": between(0, 1, lo_open=True),
        "epochs": at_least(1), "minibatch": at_least(1), "lr": between(0, 1), "vf_coef": at_least(0, False),
        "entropy_coef": at_least(0, False), "kl_coef": at_least(0, False), "kl_target": above(0), "kl_stop": at_least(0, False),
        "max_grad_norm": above(0), "behaviour_weight_max": at_least(1, False),
    }
    """Allowed values of the numeric fields (`common.config_limits`)."""

    def validate(self) -> None:
        """ValueError naming the first value outside what is allowed."""
        check_limits(self)
        if self.lr_schedule not in ("constant", "linear", "adaptive"):
            raise ValueError(f"--ppo.lr-schedule = {self.lr_schedule!r}: give constant, linear or adaptive")



@dataclass
class Batch:
    """Time-major tensors, `T` steps by `B` environment streams."""

    obs: torch.Tensor  # [T, B, obs_dim] raw
    next_obs: torch.Tensor  # [T, B, obs_dim] raw, before reset
    actions: torch.Tensor  # [T, B, act_dim]
    logp: torch.Tensor  # [T, B] behaviour log-probabilities
    rewards: torch.Tensor  # [T, B]
    terminated: torch.Tensor  # [T, B] bool
    truncated: torch.Tensor  # [T, B] bool

    def to(self, device: torch.device) -> "Batch":
        return self if self.obs.device == device else Batch(*(getattr(self, f.name).to(device) for f in dataclasses.fields(self)))


def gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    next_values: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    gamma: float,
    lam: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalized advantage estimation (Schulman et al. 2016), `[T, B]` in, `[T, B]` out.

    `next_values[t]` is V of the observation after step t, before any reset. A terminated
    step does not bootstrap (`delta = r - V`); a truncated one does (`delta = r + gamma V' - V`).
    Both end the recursion, since the next row belongs to a new episode. The last row
    bootstraps from `next_values[-1]` through its delta only.

    Returns (advantages, returns = advantages + values).
    """
    not_term = (~terminated).to(values.dtype)
    episode_continues = (~(terminated | truncated)).to(values.dtype)
    deltas = rewards + gamma * next_values * not_term - values
    adv = torch.zeros_like(values)
    running = torch.zeros_like(values[0])
    for t in range(values.shape[0] - 1, -1, -1):
        running = deltas[t] + gamma * lam * episode_continues[t] * running
        adv[t] = running
    return adv, adv + values


def ppo_losses(
    dist: torch.distributions.Normal,
    actions: torch.Tensor,
    old_logp: torch.Tensor,
    advantages: torch.Tensor,
    values: torch.Tensor,
    returns: torch.Tensor,
    cfg: PPOConfig,
    weights: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """Clipped surrogate (Schulman 2017 eq. 7), value MSE, entropy, KL(old||new) penalty.

    Shapes: `actions [M, act_dim]`, everything else `[M]`. The KL uses the k3 estimator
    `(r - 1) - log r` with `r = pi_new / pi_old` on samples from the old policy: unbiased and
    non-negative, and it needs no old distribution parameters on the wire. With `weights`
    (decoupled PPO: `old_logp` is the proximal policy's, the samples the behaviour policy's),
    the surrogate and the KL of each sample are importance-weighted by them.
    """
    logp = dist.log_prob(actions).sum(-1)
    log_ratio = logp - old_logp
    ratio = log_ratio.exp()
    w = torch.ones_like(ratio) if weights is None else weights
    surrogate = torch.min(ratio * advantages, ratio.clamp(1 - cfg.clip, 1 + cfg.clip) * advantages)
    policy_loss = -(w * surrogate).mean()
    value_loss = 0.5 * (values - returns).square().mean()
    entropy = dist.entropy().sum(-1).mean()
    kl = (w * ((ratio - 1) - log_ratio)).mean()
    total = policy_loss + cfg.vf_coef * value_loss - cfg.entropy_coef * entropy + cfg.kl_coef * kl
    clip_frac = ((ratio - 1).abs() > cfg.clip).float().mean()
    return {"total": total, "policy": policy_loss, "value": value_loss, "entropy": entropy, "kl": kl, "clip_frac": clip_frac}


class PPO:
    """Owns the policy, the value net and one Adam optimizer over both."""

    def __init__(self, policy: GaussianPolicy, value: ValueNet, cfg: PPOConfig):
        self.policy, self.value, self.cfg = policy, value, cfg
        # NOTE: fused Adam: on CPU the default per-tensor path cost a quarter of each update.
        self.optimizer = torch.optim.Adam([*policy.parameters(), *value.parameters()], lr=cfg.lr, fused=True)
        self.lr = cfg.lr
        self.skipped_updates = 0
        """Minibatches whose loss was not finite (skipped, never applied)."""

    def set_progress(self, fraction_done: float) -> None:
        """Apply the learning-rate schedule for a run that is `fraction_done` through its budget."""
        if self.cfg.lr_schedule == "linear":
            self.lr = self.cfg.lr * max(0.0, 1.0 - fraction_done)
        elif self.cfg.lr_schedule not in ("constant", "adaptive"):
            raise ValueError(f"lr_schedule {self.cfg.lr_schedule!r} is not one of constant | linear | adaptive")
        self._apply_lr()

    def restore_lr(self, saved_lr: float) -> None:
        """On resume: the adaptive schedule's step size is state and comes back; the constant
        and linear schedules follow the config, so `--ppo.lr` on a resumed run takes effect
        (the optimizer's state dict would otherwise bring the old rate back)."""
        if self.cfg.lr_schedule == "adaptive":
            self.lr = saved_lr
        self._apply_lr()

    def _apply_lr(self) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = self.lr

    @torch.no_grad()
    def values_of(self, obs_raw: torch.Tensor) -> torch.Tensor:
        return self.value(self.policy.normalizer(obs_raw))

    @torch.no_grad()
    def log_prob(self, obs_raw: torch.Tensor, actions: torch.Tensor, chunk: int = 8192) -> torch.Tensor:
        """`[n]` log-probabilities of `actions [n, act_dim]` under the current policy."""
        return torch.cat([self.policy.distribution(obs_raw[i:i + chunk]).log_prob(actions[i:i + chunk]).sum(-1)
                          for i in range(0, obs_raw.shape[0], chunk)])

    def update(self, batch: Batch, generator: torch.Generator | None = None, sync: GradientSync | None = None) -> dict[str, float]:
        """GAE, the value targets' statistics, `epochs` passes of minibatch gradient steps, then
        the observation normalizer's update.

        With `sync` (data-parallel learners, `learner.data_parallel`), every replica runs this on
        the whole batch with the same generator, so all draw the same minibatches; each takes its
        own slice of every minibatch (`sync.slice`), and one all-reduce per step averages the
        gradients, the KL that decides the stop and the metrics. Every replica then applies the
        same step: their parameters stay equal, and the update is the single learner's up to
        the order of floating-point sums.

        The maths of `learner.ppo_reference.reference_update` (the textbook loop; a test holds the
        two to the same parameters after two updates), with less work around each minibatch
        step's matrix products (`morphmimic bench learner` times both):
        - observations are normalized once per update, not twice per minibatch (the statistics
          do not change within an update), and each epoch gathers its shuffled samples once with
          `index_select` (advanced indexing was 4x slower), so a minibatch is a slice;
        - the Gaussian's log-probability is `Normal.log_prob`'s formula without building a
          `torch.distributions.Normal` (whose argument validation ran every step);
        - terms with a zero coefficient (entropy, KL) and the metrics-only quantities are not
          differentiated; the metrics are stacked as tensors and read once at the end, not with
          eight `.item()` calls per step;
        - the gradient clip and zeroing work on parameter lists made once per update.
        """
        cfg = self.cfg
        policy, value, normalizer = self.policy, self.value, self.policy.normalizer
        T, B = batch.rewards.shape
        flat = lambda x: x.reshape(T * B, *x.shape[2:])  # noqa: E731
        # NOTE: the observation statistics move only after the epochs: the actors' log-probabilities
        # were taken with these, so the first minibatch's ratio is 1 (moving them first would
        # shift it by the normalizer's own step).
        with torch.no_grad():
            obs_n = normalizer(flat(batch.obs))
            values = value(obs_n)
            next_values = value(normalizer(flat(batch.next_obs)))
        adv, returns = gae(batch.rewards, values.view(T, B), next_values.view(T, B), batch.terminated, batch.truncated,
                           cfg.gamma, cfg.gae_lambda)
        actions, old_logp = flat(batch.actions), flat(batch.logp)
        adv, returns = flat(adv), flat(returns)
        if cfg.value_normalization:
            value.update_target_stats(returns)
        targets = value.standardize(returns)
        n = obs_n.shape[0]
        weights = None
        if cfg.proximal_anchor:
            behaviour_logp = old_logp
            old_logp = self.log_prob(flat(batch.obs), actions)
            weights = (old_logp - behaviour_logp).exp().clamp(max=cfg.behaviour_weight_max)
        per_sample = [obs_n, actions, old_logp, adv, targets] + ([] if weights is None else [weights])
        policy_params, value_params = list(policy.parameters()), list(value.parameters())
        records: list[torch.Tensor] = []
        steps = policy_steps = 0
        policy_active = True
        for _ in range(cfg.epochs):
            order = torch.randperm(n, generator=generator).to(obs_n.device)
            shuffled = [x.index_select(0, order) for x in per_sample]
            for start in range(0, n - cfg.minibatch + 1, cfg.minibatch):
                o, act, olp, a, ret, *w = (x[start : start + cfg.minibatch] for x in shuffled)
                if cfg.normalize_advantages:  # over the whole minibatch, also when replicas share it
                    a = (a - a.mean()) / (a.std() + 1e-8)
                if sync is not None:
                    o, act, olp, a, ret, *w = (x[sync.slice(cfg.minibatch)] for x in (o, act, olp, a, ret, *w))
                with torch.set_grad_enabled(policy_active):
                    policy_loss, entropy, kl, clip_frac = _policy_losses(
                        policy.mean_net(o), policy.log_std, act, olp, a, w[0] if w else None, cfg)
                value_loss = 0.5 * (value.standardized(o) - ret).square().mean()
                total = policy_loss + cfg.vf_coef * value_loss
                if cfg.entropy_coef:
                    total = total - cfg.entropy_coef * entropy
                if cfg.kl_coef:
                    total = total + cfg.kl_coef * kl
                finite = torch.isfinite(total)
                if sync is None and not finite:
                    self.skipped_updates += 1
                    continue
                for p in policy_params:
                    p.grad = None
                for p in value_params:
                    p.grad = None
                # NOTE: once the policy has stopped, only the value loss has a gradient; the
                # policy's parameters keep grad None, which Adam skips (no moment decay either).
                (total if policy_active else cfg.vf_coef * value_loss).backward()
                record = torch.stack([total, policy_loss, value_loss, entropy, kl, clip_frac]).detach()
                if sync is not None:
                    # NOTE: a replica whose loss is not finite still joins the all-reduce (the
                    # others wait in it); then every replica skips the step together.
                    finite, record = sync.average_(policy_params + value_params, record, finite)
                    if not finite:
                        self.skipped_updates += 1
                        continue
                    kl = record[4]
                measured_moving = policy_active  # this KL measures the policy as the update moved it
                if policy_active and cfg.kl_stop > 0 and policy_steps and kl.item() > cfg.kl_stop:
                    # This minibatch already moved the policy past the stop: only its value step is taken.
                    policy_active = False
                    for p in policy_params:
                        p.grad = None
                # NOTE: clipped apart: the value loss's gradient is ~100x the policy's (returns
                # of ~100), so one joint clip let the value loss set the policy's step.
                grad_norm = _clip_grad_norm_(policy_params, cfg.max_grad_norm)
                value_grad_norm = _clip_grad_norm_(value_params, cfg.max_grad_norm)
                self.optimizer.step()
                with torch.no_grad():
                    records.append(torch.cat([record, torch.stack([grad_norm.to(record), value_grad_norm.to(record),
                                                                   torch.tensor(float(measured_moving)).to(record)])]))
                steps += 1
                policy_steps += policy_active
        normalizer.update(flat(batch.obs))
        metrics: dict[str, float] = {}
        if records:
            table = torch.stack(records).double()
            sums = table.sum(0).tolist()
            names = ("total", "policy", "value", "entropy", "kl", "clip_frac", "grad_norm", "value_grad_norm")
            metrics = {k: v / steps for k, v in zip(names, sums)}
            # NOTE: the KL of the minibatches that measured the moving policy (up to and including
            # the one that stopped it), not of the later ones, which all sit at the frozen policy's.
            moving = table[:, 8]
            metrics["kl"] = float((table[:, 4] * moving).sum() / moving.sum().clamp(min=1.0))
        if cfg.lr_schedule == "adaptive" and steps:
            # Schulman et al.'s adaptive rule, applied to the step size rather than a KL weight.
            kl_mean = metrics["kl"]
            if kl_mean > 2.0 * cfg.kl_target:
                self.lr = max(self.lr / 1.5, 1e-6)
            elif kl_mean < 0.5 * cfg.kl_target:
                self.lr = min(self.lr * 1.5, 1e-2)
            self._apply_lr()
        metrics.update(
            lr=self.lr,
            explained_variance=_explained_variance(values, returns),
            value_target_std=float(value.target_std),
            skipped_updates=float(self.skipped_updates),
            log_std=self.policy.log_std.detach().mean().item(),
            minibatch_steps=float(steps),
            policy_steps=float(policy_steps),
        )
        return metrics


_LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))
_ENTROPY_CONST = 0.5 + 0.5 * math.log(2 * math.pi)


def _policy_losses(
    mean: torch.Tensor,
    log_std: torch.Tensor,
    actions: torch.Tensor,
    old_logp: torch.Tensor,
    advantages: torch.Tensor,
    weights: torch.Tensor | None,
    cfg: PPOConfig,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """`ppo_losses`' policy terms for the Gaussian `N(mean [M, act_dim], exp(log_std) [act_dim])`:
    (surrogate loss, entropy, KL, clip fraction), with `torch.distributions.Normal`'s formulas
    but none of its argument checks. The KL is differentiated only when `cfg.kl_coef` weights
    it, the entropy only when `cfg.entropy_coef` does."""
    # NOTE: the scale is expanded to the batch as `Normal` has it, so that the log-std's gradient
    # is summed over the batch in the same order (bit for bit the reference's, not just close).
    scale = log_std.exp().expand_as(mean)
    log_scale = scale.log()
    logp = (-((actions - mean) ** 2) / (2 * scale**2) - log_scale - _LOG_SQRT_2PI).sum(-1)
    log_ratio = logp - old_logp
    ratio = log_ratio.exp()
    surrogate = torch.min(ratio * advantages, ratio.clamp(1 - cfg.clip, 1 + cfg.clip) * advantages)
    policy_loss = -(surrogate if weights is None else weights * surrogate).mean()
    if cfg.entropy_coef and torch.is_grad_enabled():
        entropy = (_ENTROPY_CONST + torch.log(scale)).sum(-1).mean()
    else:  # a metric only: every row of the batch has the same entropy
        with torch.no_grad():
            entropy = (_ENTROPY_CONST + log_std.exp().log()).sum()
    with torch.set_grad_enabled(torch.is_grad_enabled() and bool(cfg.kl_coef)):
        k3 = (ratio - 1) - log_ratio
        kl = (k3 if weights is None else weights * k3).mean()
    with torch.no_grad():
        clip_frac = ((ratio - 1).abs() > cfg.clip).float().mean()
    return policy_loss, entropy, kl, clip_frac


_ZERO = torch.tensor(0.0)


def _clip_grad_norm_(params: list[nn.Parameter], max_norm: float) -> torch.Tensor:
    """`nn.utils.clip_grad_norm_(params, max_norm)` (its foreach path: the same norm and scale)
    without its per-call grouping by device and dtype; returns the norm before clipping."""
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return _ZERO
    with torch.no_grad():
        total = torch.linalg.vector_norm(torch.stack(torch._foreach_norm(grads, 2.0)), 2.0)
        torch._foreach_mul_(grads, torch.clamp(max_norm / (total + 1e-6), max=1.0))
    return total


def _explained_variance(pred: torch.Tensor, target: torch.Tensor) -> float:
    var = target.var()
    return float("nan") if var < 1e-12 else float(1 - (target - pred).var() / var)
