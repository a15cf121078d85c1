"""Vm regresses a known function of the parameters; Vbar tracks its box average (Algorithm 1, 24-26)."""

import numpy as np
import pytest

from sampler.marginal_value import MarginalValue

LOW, HIGH = np.array([0.5, -1.0]), np.array([2.0, 1.0])


def truth(p: np.ndarray) -> np.ndarray:
    """Returns in the paper's range: 40-100, worse for short legs and for large |p1|."""
    return 60.0 + 25.0 * (p[:, 0] - 0.5) - 15.0 * p[:, 1] ** 2


def test_learns_a_known_function():
    rng = np.random.default_rng(0)
    vm = MarginalValue(LOW, HIGH, hidden=(64, 64), lr=1e-3, seed=0)
    test = rng.uniform(LOW, HIGH, size=(500, 2))
    before = np.abs(vm(test) - truth(test)).max()
    for _ in range(6):  # six "iterations" of fresh rollout pairs, as the learner would send
        p = rng.uniform(LOW, HIGH, size=(4096, 2))
        vm.fit(p, truth(p) + rng.normal(0, 1.0, size=4096), steps=320, minibatch=128, rng=rng)
    err = np.abs(vm(test) - truth(test))
    assert before > 30.0  # an untrained Vm is far off: the check below can fail
    assert err.mean() < 1.5 and err.max() < 6.0, (err.mean(), err.max())
    # Vbar is the box average of Vm: 60 + 25 * 0.75 - 15 / 3 = 73.75 for `truth`.
    assert abs(vm.vbar - 73.75) < 2.0
    assert vm.temperature(1e-3) == abs(vm.vbar)


def test_restandardizing_keeps_predictions():
    rng = np.random.default_rng(1)
    vm = MarginalValue(LOW, HIGH, seed=1)
    p = rng.uniform(LOW, HIGH, size=(256, 2))
    vm.fit(p, truth(p), steps=20, minibatch=64, rng=rng)
    before = vm(p)
    vm._restandardize(vm.mu + 123.0, vm.sigma * 7.0)
    np.testing.assert_allclose(vm(p), before, rtol=1e-4, atol=1e-3)


def test_negative_average_gives_positive_floored_temperature():
    rng = np.random.default_rng(2)
    vm = MarginalValue(LOW, HIGH, seed=2)
    p = rng.uniform(LOW, HIGH, size=(512, 2))
    vm.fit(p, -truth(p), steps=10, minibatch=64, rng=rng)
    assert vm.vbar < 0
    assert vm.temperature(1e-3) == pytest.approx(-vm.vbar)
    vm.vbar = 1e-9
    vm.probe_std = 0.0
    assert vm.temperature(0.5) == 0.5


def test_temperature_is_at_least_vms_spread_when_the_average_is_near_zero():
    """Returns centred on 0 (an untrained value net): |Vbar| is about 0 but Vm spans tens of
    units; the temperature is Vm's std over the box, so MH does not collapse onto the worst shapes."""
    rng = np.random.default_rng(4)
    vm = MarginalValue(LOW, HIGH, seed=4)
    p = rng.uniform(LOW, HIGH, size=(2048, 2))
    vm.fit(p, truth(p) - 73.75, steps=200, minibatch=128, rng=rng)
    assert abs(vm.vbar) < 5.0
    spread = float(vm(vm.probe).std())
    assert spread > 8.0
    assert vm.temperature(1e-3) == pytest.approx(spread) and vm.temperature(1e-3) > abs(vm.vbar)


def test_state_resumed_on_another_box_keeps_vm_at_every_shape():
    """A curriculum resumes on a box 4x smaller and back on the whole box: Vm's inputs are
    normalized to the box, so the net is re-expressed; the probe points move into the new box."""
    rng = np.random.default_rng(6)
    a = MarginalValue(LOW, HIGH, seed=6)
    p = rng.uniform(LOW, HIGH, size=(1024, 2))
    a.fit(p, truth(p), steps=100, minibatch=128, rng=rng)
    small_low, small_high = np.array([1.0, -0.25]), np.array([1.375, 0.25])
    inside = rng.uniform(small_low, small_high, size=(200, 2))
    b = MarginalValue(small_low, small_high, seed=6)
    assert b.load_state(*a.state()) is True
    np.testing.assert_allclose(b(inside), a(inside), rtol=1e-5, atol=1e-3)
    assert np.all((b.probe >= small_low) & (b.probe <= small_high))
    c = MarginalValue(LOW, HIGH, seed=6)
    assert c.load_state(*b.state()) is True
    np.testing.assert_allclose(c(p), a(p), rtol=1e-5, atol=1e-3)
    assert MarginalValue(LOW, HIGH, seed=6).load_state(*c.state()) is False


def test_state_round_trip_continues_identically():
    rng = np.random.default_rng(3)
    a = MarginalValue(LOW, HIGH, seed=3)
    p = rng.uniform(LOW, HIGH, size=(512, 2))
    a.fit(p, truth(p), steps=30, minibatch=64, rng=np.random.default_rng(0))
    meta, arrays = a.state()
    b = MarginalValue(LOW, HIGH, seed=99)
    b.load_state(meta, arrays)
    np.testing.assert_array_equal(a(p), b(p))
    a.fit(p, truth(p), steps=30, minibatch=64, rng=np.random.default_rng(5))
    b.fit(p, truth(p), steps=30, minibatch=64, rng=np.random.default_rng(5))
    np.testing.assert_array_equal(a(p), b(p))  # Adam's moments came back too
    assert a.vbar == b.vbar
    with pytest.raises(ValueError, match="hidden sizes"):
        MarginalValue(LOW, HIGH, hidden=(8,)).load_state(meta, arrays)


def test_mismatched_pairs_are_refused():
    vm = MarginalValue(LOW, HIGH)
    with pytest.raises(ValueError, match="3 parameter rows for 2 values"):
        vm.fit(np.ones((3, 2)), np.ones(2), steps=1, minibatch=2, rng=np.random.default_rng(0))
