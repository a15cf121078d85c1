"""Changing a compiled model's masses in place (`common.characters.mass`): the fields MuJoCo derives
from the masses follow, so a uniformly heavier or lighter body keeps its centre of mass."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from common.characters import load_character
from common.characters.mass import scale_body_mass, set_body_mass


@pytest.mark.parametrize("factor", [0.5, 0.75, 1.25])
def test_uniform_scaling_keeps_the_centre_of_mass_and_scales_the_subtree_masses(factor: float) -> None:
    model = load_character("humanoid").model
    data = mujoco.MjData(model)
    data.qpos[:3] = [0.4, -0.2, 0.9]
    mujoco.mj_forward(model, data)
    com, total = data.subtree_com[1].copy(), float(model.body_subtreemass[1])
    scale_body_mass(model, model.body_mass.copy(), model.body_inertia.copy(), factor)
    mujoco.mj_forward(model, data)
    # NOTE: writing body_mass alone left subtree_com at factor x the true COM (the subtree mass stayed)
    np.testing.assert_allclose(data.subtree_com[1], com, atol=1e-9)
    assert model.body_subtreemass[1] == pytest.approx(factor * total)
    np.testing.assert_allclose(data.qpos[:3], [0.4, -0.2, 0.9])  # the simulation state did not move


def test_restoring_the_masses_restores_the_derived_fields() -> None:
    model = load_character("humanoid").model
    mass, inertia, weight = model.body_mass.copy(), model.body_inertia.copy(), model.dof_invweight0.copy()
    scale_body_mass(model, mass, inertia, 0.5)
    assert not np.allclose(model.dof_invweight0, weight)
    set_body_mass(model, mass, inertia)
    np.testing.assert_allclose(model.dof_invweight0, weight)


@pytest.mark.parametrize("bad", [np.nan, -1.0, np.inf])
def test_bad_masses_are_refused_before_anything_changes(bad: float) -> None:
    model = load_character("humanoid").model
    before = model.body_mass.copy()
    mass = before.copy()
    mass[2] = bad
    with pytest.raises(ValueError, match="finite and >= 0"):
        set_body_mass(model, mass, model.body_inertia.copy())
    np.testing.assert_array_equal(model.body_mass, before)
