"""`morphmimic character FILE.xml` on MJCF of any origin: it builds what MuJoCo compiles (with a
free-jointed root) or refuses the file on one line naming it and the reason, exit code 2.

Public files of several origins are in public_models/ (see its README); the small inline files
cover the constructs and refusals those do not (and the two reported bugs: a site given with
`fromto`, a humanoid next to a free ball).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from common.characters import ShapeError, load_character, morph
from common.characters.character import extent
from learner.commands.character import main
from tests.common.characters.conftest import REPO, divergence_count

PUBLIC = Path(__file__).parent / "public_models"
BUILDS = ["humanoid.xml", "humanoid100.xml", "humanoid_CMU.xml", "ant.xml"]
HUMANOID = (PUBLIC / "humanoid.xml").read_text()
BALL = '<body pos="1 0 .2"><freejoint/><geom type="sphere" size=".1"/></body>'  # unnamed, as props often are

ACCEPTED = {  # name (the constructs it exercises): file text that must build
    "site_fromto": '<mujoco><worldbody><body name="r" pos="0 0 1"><freejoint/><geom type="capsule" fromto="0 0 0 0 0 .5" '
                   'size=".05"/><site name="s" type="capsule" fromto="0 0 0 .3 0 0" size=".02"/></body></worldbody></mujoco>',
    "ball_then_humanoid": HUMANOID.replace("<worldbody>", "<worldbody>" + BALL),
    "frames_mesh_ball_joint_radian": (
        '<mujoco><compiler angle="radian"/><asset><mesh name="m" vertex="0 0 0 .1 0 0 0 .1 0 0 0 .1 .1 .1 .1"/></asset>'
        '<worldbody><frame pos="0 0 1" euler="0 0 .5"><body name="r"><freejoint/><geom type="mesh" mesh="m" pos=".1 .2 .3" '
        'euler=".1 .2 .3"/><frame pos=".2 0 0" axisangle="1 0 0 1.57"><body name="c"><joint type="ball" range="0 1.2"/>'
        '<geom type="box" size=".05 .05 .1" euler="0 .3 0"/><camera name="cam" pos="1 0 0" xyaxes="0 1 0 0 0 1"/>'
        '</body></frame></body></frame></worldbody></mujoco>'),
    "replicate_settotalmass_unlimited_hinge": (
        '<mujoco><compiler settotalmass="10"/><worldbody><body name="r" pos="0 0 .5"><freejoint/>'
        '<geom type="box" size=".3 .1 .05"/><replicate count="4" offset=".15 0 0"><body pos="-.2 .1 0" euler="-30 0 0">'
        '<joint type="hinge"/><geom type="cylinder" fromto="0 0 0 0 .1 -.2" size=".02"/></body></replicate></body>'
        '</worldbody></mujoco>'),
    "actuator_by_class_prop_keyframe": (
        '<mujoco><default><default class="act"><position kp="50" ctrlrange="-1 1"/></default></default><worldbody>'
        '<body name="prop"><freejoint/><geom size=".1"/></body><body name="r" pos="0 0 1"><freejoint/><geom size=".1"/>'
        '<body><joint name="h" type="hinge"/><geom type="box" size=".05 .05 .1" pos="0 0 -.2"/></body></body></worldbody>'
        '<actuator><position class="act" joint="h"/></actuator><sensor><framepos objtype="body" objname="prop"/>'
        '</sensor><keyframe><key qpos="5 0 0 1 0 0 0 0 0 1 1 0 0 0 .3"/></keyframe></mujoco>'),
    "camera_light_tendon_on_prop": (
        '<mujoco><worldbody><light mode="targetbody" target="ball" pos="0 0 3"/><camera mode="targetbody" target="ball"/>'
        '<body name="ball" pos="1 0 .2"><freejoint/><geom size=".1"/><site name="bs"/></body><body name="r" pos="0 0 1">'
        '<freejoint/><geom size=".1"/><site name="rs"/></body></worldbody><tendon><spatial name="t"><site site="rs"/>'
        '<site site="bs"/></spatial></tendon><actuator><motor tendon="t"/></actuator></mujoco>'),
}

REFUSED = {  # name: (file text, what the one-line refusal must say)
    "no_free_root": ('<mujoco><worldbody><body><joint type="hinge"/><geom size=".1"/></body></worldbody></mujoco>',
                     "no free-jointed root body"),
    "not_xml": ("this is { not xml", "does not parse as MJCF"),
    "not_mjcf": ("<html><body>hello</body></html>", "Unrecognized XML model type: 'html'"),
    "missing_mesh": (('<mujoco><asset><mesh name="m" file="nothere.stl"/></asset><worldbody><body><freejoint/>'
                      '<geom type="mesh" mesh="m"/></body></worldbody></mujoco>'), "nothere.stl"),
    "missing_include": (('<mujoco><include file="nothere.xml"/><worldbody><body><freejoint/><geom size=".1"/>'
                         '</body></worldbody></mujoco>'), "nothere.xml"),
    "site_fromto_sphere": (('<mujoco><worldbody><body><freejoint/><geom size=".1"/><site fromto="0 0 0 1 0 0"/>'
                            '</body></worldbody></mujoco>'), "fromto requires capsule"),
    "no_geoms": (('<mujoco><worldbody><body name="r"><freejoint/><inertial pos="0 0 0" mass="1" '
                  'diaginertia=".1 .1 .1"/></body></worldbody></mujoco>'), "has no geoms"),
    "mesh_in_scaled_frame": (
        ('<mujoco><asset><mesh name="m" vertex="0 0 0 .1 0 0 0 .1 0 0 0 .1 .1 .1 .1"/></asset><worldbody><body '
         'name="r" pos="0 0 1"><freejoint/><geom size=".1"/><frame scale="2 2 2"><body name="c"><joint/>'
         '<geom type="mesh" mesh="m"/></body></frame></body></worldbody></mujoco>'), "cannot be imported"),
}


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    """MuJoCo writes MUJOCO_LOG.TXT into the working directory on a warning: keep it out of the repo."""
    monkeypatch.chdir(tmp_path)


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / f"{name}.xml"
    path.write_text(text)
    return path


def _character_bodies(path: Path) -> list[str]:
    """Bodies of MuJoCo's own compile of `path` in the subtree of its free top-level body with the
    most bodies (the character; other top-level bodies are props), world first."""
    m = mujoco.MjModel.from_xml_path(str(path))
    free = [b for b in range(1, m.nbody) if m.body_parentid[b] == 0 and mujoco.mjtJoint.mjJNT_FREE in
            m.jnt_type[m.body_jntadr[b]:m.body_jntadr[b] + m.body_jntnum[b]]]
    root = max(free, key=lambda b: int(np.sum(m.body_rootid == b)))
    return ["world"] + [m.body(b).name for b in np.flatnonzero(m.body_rootid == root)]


def _check_builds(path: Path, tmp_path: Path, capsys) -> None:
    """Body count as MuJoCo compiles the character, on the floor at rest, 300 steps without
    divergence, a uniform re-shape scales the mass by s^3, the CLI writes a loadable MJCF."""
    ch = load_character(str(path))
    assert ch.model.nbody == len(_character_bodies(path))
    assert ch.model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE and ch.model.jnt_bodyid[0] == ch.model.body(ch.root_body).id
    data = ch.make_data()
    assert abs(extent(ch.model, data, 2)[0]) < 1e-6
    for _ in range(300):
        mujoco.mj_step(ch.model, data)
    assert np.all(np.isfinite(data.qpos)) and divergence_count(data) == 0
    if not any(ch.model.geom_type[ch.model.geom_bodyid > 0] == mujoco.mjtGeom.mjGEOM_MESH):
        big = load_character(str(path), {"scale": 1.2}, "uniform")
        assert big.mass_kg == pytest.approx(ch.mass_kg * 1.2**3, rel=1e-3)
    out = tmp_path / "out.xml"
    assert main([str(path), "--mjcf", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    assert mujoco.MjModel.from_xml_path(str(out)).nbody == ch.model.nbody


def _check_refused(path: Path, reason: str, capsys) -> None:
    """ShapeError and CLI exit 2 with one stderr line naming the file and the reason."""
    with pytest.raises(ShapeError, match=str(path)) as err:
        load_character(str(path))
    assert reason in str(err.value) and "\n" not in str(err.value)
    assert main([str(path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and reason in lines[0]


@pytest.mark.parametrize("name", BUILDS)
def test_public_model_builds(name, tmp_path, capsys):
    _check_builds(PUBLIC / name, tmp_path, capsys)


def test_public_model_without_free_joint_is_refused(capsys):
    _check_refused(PUBLIC / "half_cheetah.xml", "no free-jointed root body", capsys)


@pytest.mark.parametrize("name", ACCEPTED)
def test_construct_builds(name, tmp_path, capsys):
    _check_builds(_write(tmp_path, name, ACCEPTED[name]), tmp_path, capsys)


@pytest.mark.parametrize("name", REFUSED)
def test_bad_file_is_refused_on_one_line(name, tmp_path, capsys):
    text, reason = REFUSED[name]
    _check_refused(_write(tmp_path, name, text), reason, capsys)


def test_missing_file_and_directory_are_refused(tmp_path, capsys):
    _check_refused(tmp_path / "missing.xml", "does not exist", capsys)
    _check_refused(tmp_path, "is not a file", capsys)


def test_site_fromto_keeps_its_place(tmp_path):
    """Regression: a `fromto` site stopped the import with MuJoCo's error and no file name."""
    path = _write(tmp_path, "site", ACCEPTED["site_fromto"])
    ch = load_character(str(path))
    own = mujoco.MjModel.from_xml_path(str(path))
    assert np.allclose(ch.model.site_pos, own.site_pos) and np.allclose(ch.model.site_size, own.site_size)
    assert np.allclose(np.abs(ch.model.site_quat @ own.site_quat.T), 1.0)


def test_humanoid_next_to_a_free_ball_leaves_the_ball_out(tmp_path):
    """Regression: a second (unnamed) free body crashed with a KeyError. The humanoid (most
    bodies) is the character even though the ball comes first; the ball is left out."""
    ch = load_character(str(_write(tmp_path, "ball", ACCEPTED["ball_then_humanoid"])))
    assert ch.root_body == "torso" and ch.model.nq == 28 and ch.model.nu == 21
    assert [ch.model.body(b).name for b in range(ch.model.nbody)] == _character_bodies(PUBLIC / "humanoid.xml")


def test_props_take_what_refers_to_them_along(tmp_path):
    """A prop's sensor and its keyframe entries go with it; the character's stay."""
    ch = load_character(str(_write(tmp_path, "prop", ACCEPTED["actuator_by_class_prop_keyframe"])))
    assert ch.model.nsensor == 0 and ch.model.nu == 1
    assert np.allclose(ch.model.key_qpos, [[0, 0, 1, 1, 0, 0, 0, 0.3]])


def test_public_model_morphs_during_simulation():
    """F on the fly (morph.py) works on an imported file: the mass follows a uniform scale."""
    ch = load_character(str(PUBLIC / "humanoid.xml"), None, "uniform")
    mass, data = ch.mass_kg, ch.make_data()
    for _ in range(20):
        mujoco.mj_step(ch.model, data)
    big, data = morph(ch, {"scale": 1.2}, data)
    for _ in range(20):
        mujoco.mj_step(big.model, data)
    assert big.mass_kg == pytest.approx(mass * 1.2**3, rel=1e-3) and np.all(np.isfinite(data.qpos))


def test_shape_that_scales_a_mesh_body_is_refused(tmp_path):
    """F cannot rescale a mesh: scaling its body is refused by name, scaling other bodies works."""
    path = _write(tmp_path, "mesh", ACCEPTED["frames_mesh_ball_joint_radian"])
    with pytest.raises(ShapeError, match="body 'r' carries a mesh geom"):
        load_character(str(path), {"scale": 1.2}, "uniform")
    assert load_character(str(path), {"c_x": 1.2}).mass_kg > load_character(str(path)).mass_kg


def test_cli_subprocess_refuses_without_traceback():
    path = PUBLIC / "half_cheetah.xml"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    run = subprocess.run([sys.executable, "-m", "learner.cli", "character", str(path)], capture_output=True, text=True,
                         env=env, timeout=120, check=False)
    assert run.returncode == 2
    expected = (f"morphmimic character: MJCF file {str(path)!r} has no free-jointed root body: a character needs "
                "a top-level body with a free joint (add <freejoint/> to its root body)")
    assert run.stderr.strip().splitlines() == [expected]
