"""Metropolis-Hastings over a parameter box (Won & Lee 2019, Sec. 4.2, Eq. 9-10; Algorithm 1 line 3).

Target density  P(s_b) ∝ exp(-k * Vm(s_b) / Vbar)  (Eq. 9's surrogate): the worse a shape is
controlled, the more often it is trained. With the paper's uniform proposal over the box (an
independence sampler: the proposal does not depend on the current state, so it cancels in the
Hastings ratio) the acceptance probability is

    rho = min(1, exp(k * (Vm(s_b) - Vm(s_b')) / Vbar))        (Eq. 10)

for the current state s_b and the proposal s_b'. Several chains run side by side, vectorized:
one Vm evaluation of `[n_chains, d]` per MH step. Pure numpy; `vm` is any callable.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class MCMCResult:
    samples: np.ndarray
    """`[n_samples, d]` float64 draws, chain-interleaved then shuffled."""
    acceptance_rate: float
    """Accepted proposals / proposals over all chains and steps (burn-in included)."""
    values: np.ndarray
    """`[n_samples]` Vm at each sample (already computed by the chains; reused for stats)."""


def metropolis_hastings(
    vm: Callable[[np.ndarray], np.ndarray],
    low: np.ndarray,
    high: np.ndarray,
    k: float,
    temperature: float,
    n_samples: int,
    n_chains: int,
    burn_in: int,
    thin: int,
    rng: np.random.Generator,
) -> MCMCResult:
    """Draw `n_samples` from exp(-k * vm(x) / temperature) on the box [low, high]^d.

    `vm` maps `[n, d]` -> `[n]`; `temperature` is |Vbar| floored by the caller (positive).
    Chains start at uniform points, discard `burn_in` steps, then keep every `thin`-th state
    until each has given ceil(n_samples / n_chains) samples; the surplus is dropped at random.

    NOTE: the ratio is evaluated in log space (log u < k (Vm - Vm') / T), so a sharp density
    (large k, tiny T) cannot overflow exp(); it only lowers the acceptance rate.
    """
    low = np.asarray(low, dtype=np.float64)
    high = np.asarray(high, dtype=np.float64)
    if temperature <= 0 or not np.isfinite(temperature):
        raise ValueError(f"temperature = {temperature!r}; it must be a positive finite number (|Vbar| floored)")
    if k < 0:
        raise ValueError(f"k = {k!r}; the uniformity knob must be >= 0")
    d = low.shape[0]
    per_chain = -(-n_samples // n_chains)
    scale = k / temperature
    x = rng.uniform(low, high, size=(n_chains, d))
    vx = np.asarray(vm(x), dtype=np.float64)
    kept_x = np.empty((per_chain, n_chains, d))
    kept_v = np.empty((per_chain, n_chains))
    accepted = 0
    total_steps = burn_in + per_chain * thin
    for step in range(total_steps):
        y = rng.uniform(low, high, size=(n_chains, d))
        vy = np.asarray(vm(y), dtype=np.float64)
        accept = np.log(rng.uniform(size=n_chains)) < scale * (vx - vy)
        x = np.where(accept[:, None], y, x)
        vx = np.where(accept, vy, vx)
        accepted += int(accept.sum())
        kept = step - burn_in + 1
        if kept > 0 and kept % thin == 0:
            kept_x[kept // thin - 1] = x
            kept_v[kept // thin - 1] = vx
    flat_x = kept_x.reshape(-1, d)
    flat_v = kept_v.reshape(-1)
    pick = rng.permutation(flat_x.shape[0])[:n_samples]
    return MCMCResult(samples=flat_x[pick], acceptance_rate=accepted / max(total_steps * n_chains, 1),
                      values=flat_v[pick])
