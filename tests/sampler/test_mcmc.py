"""The MCMC buffer follows exp(-k Vm / T) (Won & Lee 2019, Eq. 9-10), and k = 0 is uniform."""

import numpy as np
import pytest
from scipy import stats

from sampler.mcmc import metropolis_hastings

CHAINS = dict(n_samples=1000, n_chains=32, burn_in=100, thin=4)


def linear_vm(x: np.ndarray) -> np.ndarray:
    return x[:, 0]


def exp_cdf(rate: float):
    """CDF on [0, 1] of the density ∝ exp(-rate x)."""
    return lambda x: (1 - np.exp(-rate * np.asarray(x))) / (1 - np.exp(-rate))


def test_1d_matches_target_density_and_rejects_wrong_ones():
    # k = 2, T = 0.5: density ∝ exp(-4 x) on [0, 1].
    res = metropolis_hastings(linear_vm, np.zeros(1), np.ones(1), 2.0, 0.5, rng=np.random.default_rng(0), **CHAINS)
    x = res.samples[:, 0]
    assert res.samples.shape == (1000, 1)
    assert 0.0 < res.acceptance_rate < 1.0
    assert stats.kstest(x, exp_cdf(4.0)).pvalue > 0.01
    # The same samples must look wrong against a uniform and against half the sharpness.
    assert stats.kstest(x, "uniform").pvalue < 1e-3
    assert stats.kstest(x, exp_cdf(2.0)).pvalue < 1e-3
    np.testing.assert_allclose(res.values, x)


def _bin_probs(density, edges: np.ndarray, fine: int = 400) -> np.ndarray:
    g = (np.arange(fine) + 0.5) / fine
    gx, gy = np.meshgrid(g, g, indexing="ij")
    w = density(np.stack([gx.ravel(), gy.ravel()], axis=1)).reshape(fine, fine)
    h, _, _ = np.histogram2d(gx.ravel(), gy.ravel(), bins=[edges, edges], weights=w.ravel())
    return (h / h.sum()).ravel()


def test_2d_matches_target_density_by_chi_square():
    def vm(x):
        return np.sin(3 * x[:, 0]) + 2 * (x[:, 1] - 0.3) ** 2

    k, temp = 3.0, 1.0
    res = metropolis_hastings(vm, np.zeros(2), np.ones(2), k, temp, rng=np.random.default_rng(1), **CHAINS)
    edges = np.linspace(0, 1, 5)
    counts, _, _ = np.histogram2d(res.samples[:, 0], res.samples[:, 1], bins=[edges, edges])
    counts = counts.ravel()
    right = _bin_probs(lambda x: np.exp(-k * vm(x) / temp), edges)
    wrong = _bin_probs(lambda x: np.exp(-0.3 * k * vm(x) / temp), edges)
    assert stats.chisquare(counts, right * counts.sum()).pvalue > 0.01
    assert stats.chisquare(counts, wrong * counts.sum()).pvalue < 1e-3


def test_k_zero_is_uniform_and_accepts_everything():
    low, high = np.array([-1.0, 0.5, 10.0]), np.array([1.0, 2.0, 10.5])
    res = metropolis_hastings(lambda x: x.sum(axis=1), low, high, 0.0, 1.0, rng=np.random.default_rng(2), **CHAINS)
    assert res.acceptance_rate == 1.0
    for i in range(3):
        assert stats.kstest(res.samples[:, i], "uniform", args=(low[i], high[i] - low[i])).pvalue > 0.01
    # A sharp density on the same dimension is not uniform: the test can tell.
    sharp = metropolis_hastings(lambda x: x.sum(axis=1), low, high, 5.0, 1.0, rng=np.random.default_rng(2), **CHAINS)
    assert stats.kstest(sharp.samples[:, 0], "uniform", args=(-1.0, 2.0)).pvalue < 1e-3


def test_sharp_density_does_not_overflow():
    res = metropolis_hastings(lambda x: 1e6 * x[:, 0], np.zeros(1), np.ones(1), 50.0, 1e-3,
                              rng=np.random.default_rng(3), **CHAINS)
    assert np.isfinite(res.samples).all()
    assert np.median(res.samples) < 0.05


@pytest.mark.parametrize("k,temp", [(-1.0, 1.0), (1.0, 0.0), (1.0, float("nan"))])
def test_bad_arguments_name_the_value(k, temp):
    with pytest.raises(ValueError, match="k =|temperature ="):
        metropolis_hastings(linear_vm, np.zeros(1), np.ones(1), k, temp, rng=np.random.default_rng(0), **CHAINS)
