"""Standing pose, simulation without divergence, swimming, shape change during simulation."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from common.characters import list_presets, load_character, morph
from tests.common.characters.conftest import FISH_XML, LEGGED, divergence_count, floor_penetration_m, foot_vertex_heights


@pytest.mark.parametrize("preset", LEGGED)
def test_pose_solve_puts_every_foot_vertex_on_the_ground(preset):
    rng = np.random.default_rng(7)
    space = load_character(preset).space
    worst = 0.0
    for _ in range(50):
        ch = load_character(preset, space.sample(rng))
        worst = max(worst, float(np.abs(foot_vertex_heights(ch, ch.standing_qpos)).max()))
    assert worst < 2e-3


def test_pose_solve_bends_the_longer_leg():
    ch = load_character("lower_biped", {"left_leg": 1.1, "right_leg": 0.9}, "left_right_leg")
    q = ch.standing_qpos
    assert np.abs(foot_vertex_heights(ch, q)).max() < 2e-3
    knee_l = q[ch.qpos_slices["TibiaL"]][0]
    knee_r = q[ch.qpos_slices["TibiaR"]][0]
    assert abs(knee_l) > abs(knee_r) + 0.1


def _simulate(ch, seconds: float, rng: np.random.Generator | None) -> mujoco.MjData:
    m = ch.model
    d = ch.make_data()
    substeps = int(round(1.0 / 30.0 / m.opt.timestep))
    lo, hi = m.actuator_ctrlrange.T
    for _ in range(int(seconds * 30)):
        d.ctrl[:] = rng.uniform(lo, hi) if rng is not None else 0.0
        for _ in range(substeps):
            mujoco.mj_step(m, d)
    return d


@pytest.mark.parametrize("preset", list_presets())
@pytest.mark.parametrize("actions", ["zero", "random"])
def test_ten_seconds_without_divergence(preset, actions):
    rng = np.random.default_rng(3)
    space = load_character(preset).space
    # Random actions on a random shape; zero actions on the box corner of smallest values.
    shape = space.sample(rng) if actions == "random" else space.low
    ch = load_character(preset, shape)
    d = _simulate(ch, 10.0, rng if actions == "random" else None)
    assert divergence_count(d) == 0
    assert np.all(np.isfinite(d.qpos)) and d.time == pytest.approx(10.0, abs=0.01)


def _flap(ch, seconds: float) -> float:
    """Travelling-wave targets (head to tail / root to wing tip); returns forward distance (m)."""
    m, d = ch.model, ch.make_data()
    x0 = d.qpos[0]
    names = ch.actuator_names
    for _ in range(int(seconds / m.opt.timestep)):
        for i, n in enumerate(names):
            if n.endswith("_yaw") and n.startswith("seg"):
                d.ctrl[i] = 0.5 * np.sin(2 * np.pi * 1.5 * d.time - 0.8 * int(n[3]))
            elif n.endswith("_flap"):
                d.ctrl[i] = 0.6 * np.sin(2 * np.pi * 1.0 * d.time - 0.7 * int(n.split("_flap")[0][-1]))
        mujoco.mj_step(m, d)
    assert divergence_count(d) == 0
    return float(d.qpos[0] - x0)


@pytest.mark.parametrize("preset", ["fish", "manta"])
def test_flapping_swimmer_moves_forward(preset):
    ch = load_character(preset)
    assert _flap(ch, 4.0) > 0.5  # metres in 4 s; still it drifts < 0.05 m (no gravity, no current)


def test_still_swimmer_does_not_drift():
    ch = load_character("fish")
    d = _simulate(ch, 2.0, None)
    assert np.linalg.norm(d.qpos[:3] - ch.standing_qpos[:3]) < 0.05


def test_user_mjcf_is_scaled_and_simulated():
    ch = load_character(f"mjcf:{FISH_XML}", {"scale": 1.4}, "uniform")
    m, d = ch.model, ch.make_data()
    for _ in range(int(3.0 / m.opt.timestep)):
        d.ctrl[:] = np.sin(2 * np.pi * 2.0 * d.time + np.arange(m.nu))
        mujoco.mj_step(m, d)
    assert divergence_count(d) == 0
    assert np.linalg.norm(d.qpos[:3] - ch.standing_qpos[:3]) > 1e-3  # the tail moved it


def test_legs_growing_mid_simulation_do_not_penetrate_the_floor():
    ch = load_character("biped", {"leg_length": 1.0}, "leg_arm")
    d = ch.make_data()
    m = ch.model
    for _ in range(60):
        mujoco.mj_step(m, d)
    qvel_before, time_before = d.qvel.copy(), d.time
    for k in range(1, 11):
        ch, d = morph(ch, {"leg_length": 1.0 + 0.08 * k}, d)
        assert floor_penetration_m(ch.model, d) < 1e-3
        for _ in range(16):
            mujoco.mj_step(ch.model, d)
    assert ch.shape[0] == pytest.approx(1.8)
    assert d.time > time_before
    assert divergence_count(d) == 0
    ch2, d2 = morph(ch, {"leg_length": 1.8}, d)
    np.testing.assert_allclose(d2.qvel, d.qvel)  # the state is carried over
    assert qvel_before.shape == d2.qvel.shape


def test_morph_rejects_bad_shape_before_changing_anything():
    from common.characters import ShapeError

    ch = load_character("lower_biped", None, "left_right_leg")
    d = ch.make_data()
    with pytest.raises(ShapeError):
        morph(ch, {"left_leg": 3.0}, d)
    assert ch.spec.compile().body_mass.sum() == pytest.approx(ch.mass_kg)
