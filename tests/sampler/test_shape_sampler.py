"""ShapeSampler: draws from the buffer, adapts to Vm, refuses bad pairs, round-trips its state."""

import dataclasses
import io

import numpy as np
import pytest
import torch
from scipy import stats

from common import wire
from common.params import ParamError, ParamSpace
from common.motion.balancer import load_clip_labels
from sampler.config import SamplerConfig
from sampler.shape_sampler import ShapeSampler, state_from_torch, state_to_torch

SPACE = ParamSpace(names=("leg", "arm"), low=(0.5, 0.5), high=(2.0, 1.5))
FAST = SamplerConfig(k=5.0, p_mcmc=2, n_mcmc=500, n_chains=16, burn_in=50, thin=3, vm_fit_steps=60,
                     vm_minibatch=128, probe_points=256, seed=7)


def episode_values(p: np.ndarray) -> np.ndarray:
    """Short legs are hard: returns grow with leg length, arms do not matter."""
    return 40.0 + 40.0 * (p[:, 0] - 0.5)


def run(sampler: ShapeSampler, iterations: range, values=episode_values) -> dict[str, float]:
    out = {}
    for it in iterations:
        p, _ = sampler.draw(256)
        sampler.report(p, values(p))
        out = sampler.tick(it)
    return out


def test_draws_are_a_shuffled_pass_over_the_buffer_with_clips():
    s = ShapeSampler(FAST, SPACE, load_clip_labels())
    p, clips = s.draw(FAST.n_mcmc)
    assert p.shape == (FAST.n_mcmc, 2) and len(clips) == FAST.n_mcmc
    np.testing.assert_array_equal(np.sort(p, axis=0), np.sort(s.buffer, axis=0))
    assert set(clips) <= {c for c, _ in load_clip_labels()}
    assert s.draw(3)[0].shape == (3, 2) and s.draws_served == FAST.n_mcmc + 3
    assert ShapeSampler(FAST, SPACE).draw(2)[1] == []
    with pytest.raises(ValueError, match=r"n = 0.*\[1, 65536\]"):
        s.draw(0)


def test_adaptive_buffer_oversamples_hard_shapes_and_k_zero_stays_uniform():
    adaptive = ShapeSampler(FAST, SPACE)
    st = run(adaptive, range(1, 7))
    assert st["buffer/generation"] == 3 and 0 < st["mcmc/acceptance"] < 1
    assert st["vm/min"] < 50 < 90 < st["vm/max"]
    # Uniform leg mean is 1.25; the hard (short-leg) end must dominate, arms stay uniform.
    assert st["buffer/mean/leg"] < 1.0
    assert abs(st["buffer/mean/arm"] - 1.0) < 0.1
    uniform = ShapeSampler(dataclasses.replace(FAST, k=0.0), SPACE)
    st0 = run(uniform, range(1, 7))
    assert st0["mcmc/acceptance"] == 1.0
    assert stats.kstest(uniform.buffer[:, 0], "uniform", args=(0.5, 1.5)).pvalue > 0.01
    assert stats.kstest(adaptive.buffer[:, 0], "uniform", args=(0.5, 1.5)).pvalue < 1e-6


def test_negative_returns_still_favour_the_hard_shapes():
    s = ShapeSampler(FAST, SPACE)
    st = run(s, range(1, 7), values=lambda p: episode_values(p) - 200.0)  # all returns < 0
    assert st["vm/vbar"] < 0 < st["vm/temperature"]
    assert st["buffer/mean/leg"] < 1.0


def test_refill_every_p_mcmc_iterations_and_repeated_ticks_are_harmless():
    s = ShapeSampler(dataclasses.replace(FAST, p_mcmc=3), SPACE)
    gens = [s.tick(it)["buffer/generation"] for it in (1, 2, 3, 3, 3, 4, 5, 6)]
    assert gens == [0, 0, 1, 1, 1, 1, 1, 2]


@pytest.mark.parametrize("params,values,match", [
    (np.array([[0.4, 1.0]]), np.array([1.0]), "'leg' = 0.4 is out of range; allowed: leg in \\[0.5, 2\\]"),
    (np.array([[1.0, np.nan]]), np.array([1.0]), "'arm' = nan"),
    (np.array([[1.0, 1.0]]), np.array([np.inf]), "must be finite"),
    (np.ones((2, 3)), np.ones(2), r"expected \[m, 2\]"),
    (np.ones((2, 2)), np.ones(3), r"expected \[2\]"),
])
def test_bad_pairs_are_refused(params, values, match):
    s = ShapeSampler(FAST, SPACE)
    with pytest.raises(ParamError, match=match):
        s.report(params, values)
    assert s.pending_pairs == 0


def test_float32_round_trip_of_a_bound_is_accepted():
    s = ShapeSampler(FAST, SPACE)
    at_bound = np.array([[0.5, 1.5]], dtype=np.float32) * np.float32(1 + 1e-7)
    s.report(at_bound, np.ones(1))
    assert s.pending_pairs == 1


def untimed(stats: dict[str, float]) -> dict[str, float]:
    """Stats without wall times (`*_s`), which differ between two runs of the same work."""
    return {k: v for k, v in stats.items() if not k.endswith("_s")}


def test_state_round_trips_through_a_weights_only_checkpoint_and_the_wire():
    a = ShapeSampler(FAST, SPACE, load_clip_labels())
    run(a, range(1, 4))
    a.draw(77)
    a.report(*[np.full((5, 2), 1.0), np.full(5, 50.0)])  # pending pairs travel too
    buf = io.BytesIO()
    torch.save(state_to_torch(a.state_dict()), buf)
    buf.seek(0)
    loaded = state_from_torch(torch.load(buf, weights_only=True))
    frames = wire.encode(wire.StateMsg(meta=loaded["meta"], arrays=loaded["arrays"]))
    msg = wire.decode([bytes(f) for f in frames])
    b = ShapeSampler(dataclasses.replace(FAST, seed=123), SPACE, load_clip_labels())
    b.load_state_dict({"meta": msg.meta, "arrays": msg.arrays})
    assert a.stats() == b.stats()
    for n in (10, 600):
        pa, ca = a.draw(n)
        pb, cb = b.draw(n)
        np.testing.assert_array_equal(pa, pb)
        assert ca == cb
    run(a, range(4, 6))
    run(b, range(4, 6))
    assert untimed(a.stats()) == untimed(b.stats())
    np.testing.assert_array_equal(a.buffer, b.buffer)


def test_state_of_another_space_is_refused():
    a = ShapeSampler(FAST, SPACE)
    other = ParamSpace(names=("height", "thickness"), low=(0.75, 0.5), high=(1.5, 1.5))
    with pytest.raises(ValueError, match=r"parameters \['leg', 'arm'\].*\['height', 'thickness'\]"):
        ShapeSampler(FAST, other).load_state_dict(a.state_dict())


def test_state_resumed_on_a_wider_or_narrower_box_keeps_its_shapes_inside_the_box():
    """A shape curriculum resumes a run with `--task.body.shape-box-scale` changed."""
    wide = ShapeSampler(FAST, SPACE)
    run(wide, range(1, 4))
    narrow_space = ParamSpace(names=SPACE.names, low=(0.9, 0.9), high=(1.1, 1.1))
    narrow = ShapeSampler(FAST, narrow_space)
    narrow.load_state_dict(wide.state_dict())
    p, _ = narrow.draw(600)
    assert np.all(p >= narrow_space.low_array) and np.all(p <= narrow_space.high_array)
    back = ShapeSampler(FAST, SPACE)
    back.load_state_dict(narrow.state_dict())
    # Refilled at once over the whole box: the narrow buffer is not served for p_mcmc iterations.
    assert back.buffer[:, 0].min() < 0.9 < 1.1 < back.buffer[:, 0].max()
    assert back.generation == narrow.generation + 1
    same = ShapeSampler(FAST, SPACE)
    same.load_state_dict(back.state_dict())
    assert same.generation == back.generation  # the same box: no refill
