"""`morphmimic character` and the offscreen PNG."""

from __future__ import annotations

import pytest

from tests.common.characters.conftest import FISH_XML


def test_cli_prints_and_writes_mjcf(tmp_path, capsys):
    from learner.commands.character import main

    out = tmp_path / "lb.xml"
    assert main(["lower_biped", "--parameterization", "left_right_leg", "--shape", "left_leg=1.05", "--mjcf", str(out)]) == 0
    text = capsys.readouterr().out
    assert "mass_kg" in text and "leg_lengths_m" in text and "dof 17" in text
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.nkey == 1 and model.nu == 17


def test_cli_bad_shape_exits_2(capsys):
    from learner.commands.character import main

    assert main(["quadruped", "--shape", "front_leg=9", "--parameterization", "front_hind_leg"]) == 2
    assert "front_leg" in capsys.readouterr().err


def test_cli_list(capsys):
    from learner.commands.character import main

    assert main(["manta", "--list"]) == 0
    assert "wing_span" in capsys.readouterr().out


@pytest.mark.render
@pytest.mark.parametrize("preset", ["lower_biped", f"mjcf:{FISH_XML}"])
def test_png_renders_the_character(tmp_path, preset):
    import imageio.v3 as iio

    from learner.commands.character import main

    png = tmp_path / "c.png"
    assert main([preset, "--png", str(png)]) == 0
    image = iio.imread(png)
    assert image.shape == (480, 640, 3)
    centre = image[120:360, 200:440].reshape(-1, 3).astype(float)
    assert centre.std(axis=0).max() > 10  # not a blank frame: body and floor differ
