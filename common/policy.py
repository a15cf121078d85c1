"""The networks: a Gaussian policy with its own observation normalizer, and a value network.

The policy module (normalizer + mean MLP + log-std) is exactly what actors need, so its
`state_dict` is what the learner publishes; the value network stays on the learner.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
from torch import nn

from common.config_limits import Limit, above, at_least, between, check_limits, validated


@dataclass(frozen=True)
@validated
class PolicyConfig:
    hidden: tuple[int, ...] = (128, 128, 128)
    """Hidden layer widths of both policy and value MLPs (Won & Lee 2019: 3 x 128 ReLU)."""
    activation: str = "relu"
    """relu | tanh | elu."""
    init_log_std: float = -0.5
    """Initial log standard deviation of every action component."""
    learn_log_std: bool = True
    """Learn the log-std by gradient; off, it moves only by the variance schedule below."""
    final_log_std: float | None = None
    """UniCon 2020's policy variance controller: anneal the mean log-std linearly from
    `init_log_std` to this over the first `log_std_anneal_steps` environment steps (None: off)."""
    log_std_anneal_steps: int = 0
    """Environment steps of the variance anneal."""
    obs_clip: float = 10.0
    """Normalized observations are clipped to [-obs_clip, obs_clip]."""

    FLAG_PREFIX: ClassVar[str] = "policy"
    LIMITS: ClassVar[dict[str, Limit]] = {
        "hidden": at_least(1), "init_log_std": between(-20, 5), "final_log_std": between(-20, 5),
        "log_std_anneal_steps": at_least(0), "obs_clip": above(0),
    }
    """Allowed values of the numeric fields (`common.config_limits`)."""

    def validate(self) -> None:
        """ValueError naming the first value outside what is allowed."""
        check_limits(self)
        if not self.hidden:
            raise ValueError(f"--policy.hidden = {self.hidden!r}: give one or more layer widths")
        if self.activation not in ("relu", "tanh", "elu"):
            raise ValueError(f"--policy.activation = {self.activation!r}: give relu, tanh or elu")



_ACTIVATIONS = {"relu": nn.ReLU, "tanh": nn.Tanh, "elu": nn.ELU}


def mlp(sizes: list[int], activation: str, out_gain: float) -> nn.Sequential:
    if activation not in _ACTIVATIONS:
        raise ValueError(f"activation {activation!r} is not one of {sorted(_ACTIVATIONS)}")
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        linear = nn.Linear(sizes[i], sizes[i + 1])
        last = i == len(sizes) - 2
        nn.init.orthogonal_(linear.weight, gain=out_gain if last else np.sqrt(2))
        nn.init.zeros_(linear.bias)
        layers.append(linear)
        if not last:
            layers.append(_ACTIVATIONS[activation]())
    return nn.Sequential(*layers)


class ObsNormalizer(nn.Module):
    """Running mean and variance (Chan et al. parallel update), stored as buffers so they
    travel inside the policy's state dict to actors and into checkpoints.

    The update is bounded, so that no single batch moves the statistics by orders of magnitude
    (one batch of 3e38 observations once set a mean of 2.7e35 and a variance of 8e73 that every
    later checkpoint kept): raw values are clipped to +-RAW_LIMIT, and once statistics exist one
    batch moves a dimension's standard deviation by at most a factor MAX_STD_STEP either way and
    its mean by at most MAX_MEAN_STEP standard deviations (at least STD_FLOOR). An honest
    batch moves them far less (its weight is its share of every observation seen); a new
    observation scale is reached over a few batches. `check` refuses statistics no bounded
    update can produce, and a checkpoint is not written with them (`Learner.state_dict`)."""

    RAW_LIMIT = 1e6
    """Raw observation values are clipped to this before they are folded in: no task observes
    more (`common.tasks.content_bounds.OBS_MAX_ABS_LIMIT`)."""
    MAX_STD_STEP = 2.0
    """Factor by which one batch may change a dimension's standard deviation, up or down."""
    MAX_MEAN_STEP = 2.0
    """Standard deviations by which one batch may move a dimension's mean."""
    STD_FLOOR = 1e-2
    """The standard deviation those steps are measured in for a dimension that has not varied yet."""

    def __init__(self, dim: int, clip: float = 10.0, eps: float = 1e-8):
        super().__init__()
        self.clip = clip
        self.eps = eps
        self.register_buffer("mean", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.tensor(0.0, dtype=torch.float64))
        self.limited_updates = 0
        """Updates that one of the steps above held back (not checkpointed: a session's count)."""

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Fold a batch `[B, dim]` of raw observations into the running statistics, bounded as
        the class docstring says; a batch holding NaN or Inf changes nothing."""
        x = x.reshape(-1, self.mean.shape[0]).to(torch.float64)
        n = x.shape[0]
        if n == 0 or not torch.isfinite(x).all():
            return
        x = x.clamp(-self.RAW_LIMIT, self.RAW_LIMIT)
        batch_mean = x.mean(0)
        batch_var = x.var(0, unbiased=False)
        total = self.count + n
        delta = batch_mean - self.mean
        new_mean = self.mean + delta * (n / total)
        m2 = self.var * self.count + batch_var * n + delta.square() * (self.count * n / total)
        new_var = (m2 / total).clamp(max=self.RAW_LIMIT**2)
        if self.count > 0:  # before the first batch the statistics are placeholders
            std = self.var.sqrt()
            unit = std.clamp(min=self.STD_FLOOR)
            held_mean = torch.minimum(torch.maximum(new_mean, self.mean - self.MAX_MEAN_STEP * unit),
                                      self.mean + self.MAX_MEAN_STEP * unit)
            held_var = torch.minimum(torch.maximum(new_var, (std / self.MAX_STD_STEP).square()),
                                     (unit * self.MAX_STD_STEP).square())
            if not (torch.equal(held_mean, new_mean) and torch.equal(held_var, new_var)):
                self.limited_updates += 1
            new_mean, new_var = held_mean, held_var
        self.mean.copy_(new_mean)
        self.var.copy_(new_var)
        self.count.copy_(total)

    def check(self) -> None:
        """ValueError naming the first statistic that is not finite or lies beyond what a bounded
        update can produce (|mean| <= RAW_LIMIT, 0 <= var <= RAW_LIMIT^2, count >= 0)."""
        limit = self.RAW_LIMIT
        for name, value, lo, hi in (("mean", self.mean, -limit, limit), ("var", self.var, 0.0, limit**2),
                                    ("count", self.count.reshape(1), 0.0, float("inf"))):
            bad = ~torch.isfinite(value) | (value < lo) | (value > hi)
            if bad.any():
                i = int(bad.nonzero()[0, 0])
                raise ValueError(f"observation normalizer {name}[{i}] = {float(value[i]):g}; allowed: finite, in "
                                 f"[{lo:g}, {hi:g}] (what a bounded update can produce)")

    CONSTANT_VAR = 1e-10
    """A dimension whose running variance is below this never varied in training."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # NOTE: a dimension that never varied in training (the shape of a policy trained on one
        # body, a state component that is constant by construction) is centred but not scaled:
        # dividing by sqrt(eps) turned a 0.1 change of a shape parameter into +-10 (the clip),
        # so a base-shape-only policy saw garbage on any other body.
        std = torch.where(self.var > self.CONSTANT_VAR, (self.var + self.eps).sqrt(), torch.ones_like(self.var))
        return ((x - self.mean.to(x.dtype)) / std.to(x.dtype)).clamp(-self.clip, self.clip)


class GaussianPolicy(nn.Module):
    """Diagonal Gaussian over actions with a state-independent log-std (PPO, Schulman 2017)."""

    def __init__(self, obs_dim: int, act_dim: int, cfg: PolicyConfig):
        super().__init__()
        self.obs_dim, self.act_dim = obs_dim, act_dim
        self.normalizer = ObsNormalizer(obs_dim, cfg.obs_clip)
        self.mean_net = mlp([obs_dim, *cfg.hidden, act_dim], cfg.activation, out_gain=0.01)
        self.log_std = nn.Parameter(torch.full((act_dim,), float(cfg.init_log_std)), requires_grad=cfg.learn_log_std)

    def distribution(self, obs_raw: torch.Tensor) -> torch.distributions.Normal:
        mean = self.mean_net(self.normalizer(obs_raw))
        return torch.distributions.Normal(mean, self.log_std.exp().expand_as(mean))

    @torch.no_grad()
    def act(self, obs_raw: np.ndarray, deterministic: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """One batched forward for `[N, obs_dim]` observations -> (actions `[N, act_dim]`, logp `[N]`)."""
        dist = self.distribution(torch.as_tensor(obs_raw, dtype=torch.float32))
        action = dist.mean if deterministic else dist.sample()
        return action.numpy(), dist.log_prob(action).sum(-1).numpy()


@torch.no_grad()
def anneal_log_std(policy: GaussianPolicy, cfg: PolicyConfig, env_steps: int) -> None:
    """Policy variance controller (UniCon 2020, METHOD.md B "Training"): set the mean of
    log sigma to the linear interpolation from `cfg.init_log_std` to `cfg.final_log_std` at
    `env_steps / cfg.log_std_anneal_steps` (held at the final value afterwards), shifting all
    components by the same amount so a learned per-component spread is kept."""
    if cfg.final_log_std is None:
        return
    frac = 1.0 if cfg.log_std_anneal_steps <= 0 else min(1.0, env_steps / cfg.log_std_anneal_steps)
    target = cfg.init_log_std + frac * (cfg.final_log_std - cfg.init_log_std)
    policy.log_std.add_(target - policy.log_std.mean())


class ValueNet(nn.Module):
    """V(s) = mu + sigma * net(s): the MLP predicts returns standardized by running statistics
    (`target_mean`, `target_std`), so its loss and gradient stay of order one whatever the
    return scale. Until `update_target_stats` is called the statistics are (0, 1) and V(s) is
    the MLP's output, as before the normalization existed."""

    TARGET_RATE_MIN = 0.05
    """Weight of the newest batch in the running return statistics once 20 batches are in
    (before that, every batch weighs the same): returns grow as the policy improves."""

    def __init__(self, obs_dim: int, cfg: PolicyConfig):
        super().__init__()
        self.net = mlp([obs_dim, *cfg.hidden, 1], cfg.activation, out_gain=1.0)
        self.register_buffer("target_mean", torch.zeros((), dtype=torch.float64))
        self.register_buffer("target_sq", torch.ones((), dtype=torch.float64))
        self.register_buffer("target_updates", torch.zeros((), dtype=torch.float64))

    @property
    def target_std(self) -> torch.Tensor:
        return (self.target_sq - self.target_mean.square()).clamp(min=1e-4).sqrt()

    def forward(self, obs_normalized: torch.Tensor) -> torch.Tensor:
        out = self.net(obs_normalized).squeeze(-1)
        return out * self.target_std.to(out.dtype) + self.target_mean.to(out.dtype)

    def standardized(self, obs_normalized: torch.Tensor) -> torch.Tensor:
        """The MLP's output: the standardized return it predicts."""
        return self.net(obs_normalized).squeeze(-1)

    def standardize(self, returns: torch.Tensor) -> torch.Tensor:
        """Returns as the MLP's training targets: (G - mu) / sigma."""
        return ((returns - self.target_mean.to(returns.dtype)) / self.target_std.to(returns.dtype))

    @torch.no_grad()
    def update_target_stats(self, returns: torch.Tensor) -> None:
        """Fold a batch of returns into the running statistics and rescale the last layer so
        that every V(s) is unchanged: PopArt's "preserve outputs precisely" (van Hasselt et al.
        2016, eq. 4): W' = W sigma / sigma', b' = (sigma b + mu - mu') / sigma'."""
        r = returns.detach().reshape(-1).to(torch.float64)
        if r.numel() == 0 or not torch.isfinite(r).all():
            return
        rate = max(1.0 / float(self.target_updates + 1), self.TARGET_RATE_MIN)
        old_mean, old_std = self.target_mean.clone(), self.target_std.clone()
        self.target_mean.mul_(1 - rate).add_(rate * r.mean())
        self.target_sq.mul_(1 - rate).add_(rate * r.square().mean())
        self.target_updates.add_(1)
        new_mean, new_std = self.target_mean, self.target_std
        last = self.net[-1]
        last.weight.mul_((old_std / new_std).to(last.weight.dtype))
        last.bias.copy_(((old_std * last.bias.double() + old_mean - new_mean) / new_std).to(last.bias.dtype))


def policy_tensors(policy: GaussianPolicy) -> dict[str, np.ndarray]:
    """The policy state dict as numpy arrays, for a WeightsMsg."""
    return {k: v.detach().cpu().numpy() for k, v in policy.state_dict().items()}


def load_policy_tensors(policy: GaussianPolicy, tensors: dict[str, np.ndarray]) -> None:
    """Load arrays from a WeightsMsg; a missing or mis-shaped entry raises ValueError naming it."""
    own = policy.state_dict()
    if set(tensors) != set(own):
        raise ValueError(f"weights keys {sorted(tensors)} do not match the policy's {sorted(own)}")
    for k, v in tensors.items():
        if tuple(v.shape) != tuple(own[k].shape):
            raise ValueError(f"weights {k!r} has shape {tuple(v.shape)}, the policy expects {tuple(own[k].shape)}")
    policy.load_state_dict({k: torch.as_tensor(np.array(v)) for k, v in tensors.items()})
