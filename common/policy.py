"""The networks: a Gaussian policy with its own observation normalizer, and a value network.

The policy module (normalizer + mean MLP + log-std) is exactly what actors need, so its
`state_dict` is what the learner publishes; the value network stays on the learner.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn


@dataclass(frozen=True)
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
    travel inside the policy's state dict to actors and into checkpoints."""

    def __init__(self, dim: int, clip: float = 10.0, eps: float = 1e-8):
        super().__init__()
        self.clip = clip
        self.eps = eps
        self.register_buffer("mean", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.tensor(0.0, dtype=torch.float64))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Fold a batch `[B, dim]` of raw observations into the running statistics."""
        x = x.reshape(-1, self.mean.shape[0]).to(torch.float64)
        n = x.shape[0]
        if n == 0:
            return
        batch_mean = x.mean(0)
        batch_var = x.var(0, unbiased=False)
        total = self.count + n
        delta = batch_mean - self.mean
        new_mean = self.mean + delta * (n / total)
        m2 = self.var * self.count + batch_var * n + delta.square() * (self.count * n / total)
        self.mean.copy_(new_mean)
        self.var.copy_(m2 / total)
        self.count.copy_(total)

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
    def __init__(self, obs_dim: int, cfg: PolicyConfig):
        super().__init__()
        self.net = mlp([obs_dim, *cfg.hidden, 1], cfg.activation, out_gain=1.0)

    def forward(self, obs_normalized: torch.Tensor) -> torch.Tensor:
        return self.net(obs_normalized).squeeze(-1)


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
