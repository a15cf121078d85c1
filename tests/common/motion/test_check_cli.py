import numpy as np
import pytest

from learner.commands import motion as cli
from common.motion.check import check_motion
from common.motion.reference import CharacterMotion
from common.motion.retarget import contact_phases

from .conftest import DEEPMIMIC, base_character


def test_check_reports_penetration(walk_clip):
    ch = base_character("humanoid")
    feet = tuple(ch.foot_geoms)
    contacts = contact_phases(walk_clip, ch.model, feet)
    ok = check_motion(CharacterMotion.from_clip(walk_clip, ch.model), feet, contacts.flags)
    sunk = walk_clip.with_(root_pos=walk_clip.root_pos - [0, 0, 0.10])
    bad = check_motion(CharacterMotion.from_clip(sunk, ch.model), feet, contacts.flags)
    assert ok.penetration_m < 0.02 and ok.stance_float_m < 0.02
    assert bad.penetration_m == pytest.approx(ok.penetration_m + 0.10, abs=0.01)
    assert ok.frames == walk_clip.num_frames and ok.fps == pytest.approx(30.0, rel=1e-3)
    assert "humanoid3d_walk" in ok.line()


def test_cli_import_then_check(tmp_path, capsys):
    assert cli.main(["import", str(DEEPMIMIC / "humanoid3d_run.txt"), "--out", str(tmp_path)]) == 0
    out = tmp_path / "humanoid3d_run.npz"
    assert out.exists() and "25 frames" in capsys.readouterr().out
    assert cli.main(["check", str(out), "humanoid3d_walk", "--random-shape", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    # per clip: the feet line, then the executor's reference raw and cleaned
    assert len(lines) == 7 and "humanoid3d_walk" in lines[4] and "pen" in lines[4]
    assert "raw limits" in lines[5] and "vel jump max" in lines[6] and "cleaned (filter 7 Hz, floor)" in lines[6]


def test_cli_reports_bad_files(tmp_path, capsys):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT A\n{\n")
    assert cli.main(["check", str(bad)]) == 1
    assert "bad.bvh" in capsys.readouterr().out
    assert cli.main(["import", str(bad), "--out", str(tmp_path)]) == 1


@pytest.mark.render
def test_view_writes_a_png_strip(tmp_path):
    import imageio.v3 as iio

    out = tmp_path / "walk.png"
    assert cli.main(["view", "humanoid3d_walk", "--out", str(out), "--frames", "3"]) == 0
    img = iio.imread(out)
    assert img.shape[1] == 3 * img.shape[0] * 240 // 360 and img.mean() > 5
    assert np.std(img) > 5  # not a blank picture


def test_check_reports_the_root_bob_and_each_root_height_rule(capsys):
    """On a quadruped with unequal leg pairs the "contact_set" rule moves the root by
    centimetres between frames; "foot_tracks" keeps it near the clip's own bob. `motion check`
    prints both figures, and refuses an unknown rule."""
    from common.motion.check import root_bob

    z = np.array([0.5, 0.52, 0.48, 0.5])
    assert root_bob(np.stack([np.zeros(4), np.zeros(4), z], axis=1)) == pytest.approx((0.04, 0.04))
    shape = ["--shape", "fl_thigh_z=1.2", "--shape", "hr_thigh_z=1.2", "--shape", "fl_shank_z=1.2",
             "--shape", "hr_shank_z=1.2"]
    figures = {}
    for rule in ("contact_set", "foot_tracks"):
        assert cli.main(["check", "procedural/quadruped", *shape, "--root-height", rule]) == 0
        line = capsys.readouterr().out.splitlines()[-1]
        figures[rule] = float(line.split(" step ")[1].split()[0])
    assert figures["contact_set"] > 2 * figures["foot_tracks"] and figures["foot_tracks"] < 10, figures
    with pytest.raises(SystemExit):
        cli.main(["check", "procedural/quadruped", "--root-height", "lowest"])
    assert "lowest" in capsys.readouterr().err


def test_cli_checks_a_mirror_image_by_id(capsys):
    assert cli.main(["check", "humanoid3d_kick", "humanoid3d_kick~mirror"]) == 0
    plain, mirrored = [line for line in capsys.readouterr().out.splitlines()[1:] if not line.startswith("  ")]
    # the kick's one hip over its joint range moves to the other side; the foot figures stay
    assert "right_hip.z" in plain and "left_hip.z" in mirrored
    assert plain.split("raw")[1].split("limits")[0] == mirrored.split("raw")[1].split("limits")[0]
    assert cli.main(["check", "humanoid3d_nope~mirror"]) == 1
    assert "each also as <id>~mirror" in capsys.readouterr().out
