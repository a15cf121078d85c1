"""The Vm map PNG (Won & Lee 2019, Fig. 6) from a sampler state."""


import pytest

from common.params import ParamSpace
from sampler.config import SamplerConfig
from sampler.plot import plot_state
from sampler.shape_sampler import ShapeSampler

CFG = SamplerConfig(p_mcmc=1, n_mcmc=300, n_chains=16, burn_in=20, vm_fit_steps=20, probe_points=64)


def trained_state(space: ParamSpace) -> dict:
    s = ShapeSampler(CFG, space)
    for it in (1, 2):
        p, _ = s.draw(200)
        s.report(p, 50 + 10 * p[:, 0])
        s.tick(it)
    return s.state_dict()


def test_png_of_two_chosen_parameters(tmp_path):
    space = ParamSpace(names=("height", "thickness", "arm"), low=(0.75, 0.5, 0.5), high=(1.5, 1.5, 1.5))
    out = plot_state(trained_state(space), space, tmp_path / "runs" / "vm.png", params=("arm", "height"))
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    with pytest.raises(ValueError, match=r"choose two different names from \['height', 'thickness', 'arm'\]"):
        plot_state(trained_state(space), space, tmp_path / "bad.png", params=("arm", "weight"))


def test_png_of_a_one_parameter_space(tmp_path):
    space = ParamSpace(names=("speed",), low=(0.5,), high=(2.0,))
    out = plot_state(trained_state(space), space, tmp_path / "vm1.png")
    assert out.read_bytes()[:4] == b"\x89PNG"


def test_no_png_when_an_axis_has_no_width(tmp_path):
    """A fixed body (the executor's humanoid, a `-fixedshape` run) has no map: nothing is written
    and matplotlib is not asked for a singular axis."""
    import warnings

    space = ParamSpace(names=("height", "arm"), low=(1.0, 0.5), high=(1.0, 1.5))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert plot_state(trained_state(space), space, tmp_path / "vm.png") is None
    assert not (tmp_path / "vm.png").exists()
    flat = ParamSpace(names=("speed",), low=(1.0,), high=(1.0,))
    assert plot_state(trained_state(flat), flat, tmp_path / "vm1.png") is None
