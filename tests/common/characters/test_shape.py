"""The shape operator F, the parameter boxes and the errors for bad input."""

from __future__ import annotations

import numpy as np
import pytest

from common.characters import ShapeError, list_presets, load_character
from tests.common.characters.conftest import FISH_XML


@pytest.mark.parametrize("preset", list_presets() + [f"mjcf:{FISH_XML}"])
def test_uniform_scale_multiplies_mass_by_cube(preset):
    base = load_character(preset)
    for s in (0.6, 1.4):
        scaled = load_character(preset, {"scale": s}, "uniform")
        assert scaled.mass_kg / base.mass_kg == pytest.approx(s**3, rel=0.01)


@pytest.mark.parametrize("preset", ["humanoid", "quadruped", "fish"])
def test_uniform_scale_scales_lengths(preset):
    base = load_character(preset)
    scaled = load_character(preset, {"scale": 1.3}, "uniform")
    assert scaled.height_m == pytest.approx(1.3 * base.height_m, rel=0.01)
    np.testing.assert_allclose(scaled.leg_lengths_m, 1.3 * base.leg_lengths_m, rtol=0.01)


def test_paper_ranges_and_names():
    ch = load_character("biped")
    spaces = ch.base.spaces
    assert {"random", "leg_arm", "left_right_leg", "height_thickness", "upper_lower_thickness"} <= set(spaces)
    leg_arm = spaces["leg_arm"]
    assert leg_arm.names == ["leg_length", "arm_length"]
    np.testing.assert_allclose(leg_arm.low, [0.5, 0.5])
    np.testing.assert_allclose(leg_arm.high, [2.0, 1.5])
    rnd = spaces["random"]
    assert rnd.names[:3] == ["global_x", "global_y", "global_z"]
    np.testing.assert_allclose(rnd.low[:3], 0.5)
    np.testing.assert_allclose(rnd.high[3:], 1.2)
    np.testing.assert_allclose(rnd.validate(None), 1.0)


def test_left_leg_longer_only_changes_left_leg():
    base = load_character("lower_biped")
    ch = load_character("lower_biped", {"left_leg": 1.1}, "left_right_leg")
    right, left = ch.leg_lengths_m
    assert right == pytest.approx(base.leg_lengths_m[0], abs=1e-6)
    assert left > base.leg_lengths_m[1] + 0.05


def test_torque_limits_scale_and_gains_do_not():
    base = load_character("humanoid")
    big = load_character("humanoid", {"scale": 1.5}, "uniform")
    np.testing.assert_allclose(big.model.actuator_gainprm[:, 0], base.model.actuator_gainprm[:, 0])
    np.testing.assert_allclose(big.model.actuator_biasprm[:, :3], base.model.actuator_biasprm[:, :3])
    np.testing.assert_allclose(big.model.actuator_forcerange, base.model.actuator_forcerange * 1.5**4, rtol=1e-6)


@pytest.mark.parametrize(
    ("shape", "parameterization", "needle"),
    [
        ({"leg_lenght": 1.2}, "leg_arm", "leg_lenght"),
        ({"leg_length": 2.5}, "leg_arm", "[0.5, 2.0]"),
        ({"arm_length": float("nan")}, "leg_arm", "arm_length"),
        ({"arm_length": "tall"}, "leg_arm", "tall"),
        ([1.0, 1.0, 1.0], "leg_arm", "expected (2,)"),
        (None, "no_such_parameterization", "no_such_parameterization"),
    ],
)
def test_bad_shapes_raise_one_shape_error(shape, parameterization, needle):
    with pytest.raises(ShapeError) as info:
        load_character("biped", shape, parameterization)
    assert needle in str(info.value)
    assert isinstance(info.value, ValueError)


def test_out_of_range_message_names_parameter_value_and_range():
    with pytest.raises(ShapeError, match=r"'leg_length' = 2.5 is outside the allowed range \[0.5, 2.0\]"):
        load_character("humanoid", {"leg_length": 2.5}, "leg_arm")


def test_unknown_preset(tmp_path):
    with pytest.raises(ShapeError, match="unknown character preset 'dragon'"):
        load_character("dragon")
    with pytest.raises(ShapeError, match="does not exist"):
        load_character(f"mjcf:{tmp_path / 'missing.xml'}")


def test_mjcf_without_free_root_or_unparsable(tmp_path):
    fixed = tmp_path / "fixed.xml"
    fixed.write_text('<mujoco><worldbody><body name="a"><joint type="hinge"/><geom size=".1"/></body></worldbody></mujoco>')
    with pytest.raises(ShapeError, match="free joint"):
        load_character(f"mjcf:{fixed}")
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody><body")
    with pytest.raises(ShapeError, match="does not parse"):
        load_character(f"mjcf:{broken}")


def test_user_mjcf_random_shape_compiles():
    ch = load_character(f"mjcf:{FISH_XML}", {"global_x": 1.3, "tail2_z": 1.2})
    assert ch.is_swimmer
    assert ch.model.nbody == 6


MODEL_FIELDS = ("body_pos", "body_mass", "body_inertia", "geom_size", "geom_pos", "geom_type", "jnt_pos",
                "actuator_forcerange", "actuator_gainprm")


@pytest.mark.parametrize("preset", ["lower_biped", "quadruped", "fish"])
def test_factory_models_are_load_characters_models_for_any_order_of_shapes(preset):
    """A CharacterFactory re-shapes one base spec: each model must equal a fresh load_character's,
    also after an earlier make and a morph have left the shared spec in another shape."""
    from common.characters import CharacterFactory, morph

    factory = CharacterFactory(preset, "random")
    rng = np.random.default_rng(7)
    shapes = [factory.space.sample(rng) for _ in range(3)]
    first = factory.make(shapes[0])
    morph(first, shapes[1], first.make_data())
    for shape in (shapes[2], shapes[0]):
        made, fresh = factory.make(shape).model, load_character(preset, shape, "random").model
        for field in MODEL_FIELDS:
            np.testing.assert_array_equal(getattr(made, field), getattr(fresh, field), err_msg=f"{preset} {field}")
    np.testing.assert_array_equal(first.model.body_mass, load_character(preset, shapes[0], "random").model.body_mass)


def test_factory_rejects_bad_input_like_load_character():
    from common.characters import CharacterFactory

    with pytest.raises(ShapeError, match="unknown parameterization 'nope'"):
        CharacterFactory("lower_biped", "nope")
    with pytest.raises(ShapeError, match="global_z"):
        CharacterFactory("lower_biped", "random").make({"global_z": 9.0})
