import mujoco
import numpy as np
import pytest

from common.motion.procedural import GENERATORS
from common.motion.qpos_map import QposMap
from common.motion.reference import CharacterMotion
from common.motion.retarget import contact_phases, foot_heights, play_on

from .conftest import base_character


@pytest.mark.parametrize("preset", sorted(GENERATORS))
def test_procedural_clip_drives_every_joint_and_loops(preset):
    ch = base_character(preset)
    clip = GENERATORS[preset](ch)
    assert clip.loop and clip.character == preset and clip.label.startswith("root/locomotion/")
    assert QposMap(clip, ch.model).undriven == ()
    np.testing.assert_allclose(clip.joint_qpos[0], clip.joint_qpos[-1], atol=1e-9)  # one whole cycle
    assert (clip.root_pos[-1, 0] - clip.root_pos[0, 0]) / clip.duration_s > 0.1  # it goes forward, over 0.1 m/s
    assert np.ptp(clip.joint_qpos, axis=0).max() > 0.2  # and actually moves its joints


def test_quadruped_trots_with_diagonal_pairs_on_the_floor():
    from common.characters import load_character

    base = base_character("quadruped")
    clip = GENERATORS["quadruped"](base)
    feet = tuple(base.foot_geoms)
    contacts = contact_phases(clip, base.model, feet)
    flags = dict(zip(feet, contacts.flags.T))
    assert np.mean(flags["fl_foot"] == flags["hr_foot"]) > 0.9  # a trot: diagonals together
    assert np.mean(flags["fl_foot"] != flags["fr_foot"]) > 0.7
    rng = np.random.default_rng(5)
    for _ in range(5):
        ch = load_character("quadruped", shape=base.space.sample(rng), parameterization="random")
        h, _ = foot_heights(ch.model, play_on(clip, ch, base, contacts=contacts).qpos_frames, feet)
        assert np.abs(h[contacts.flags]).max() < 0.05


def test_fish_wave_grows_toward_the_tail():
    ch = base_character("fish")
    clip = GENERATORS["fish"](ch)
    yaw = [i for i, n in enumerate(clip.joint_names) if n.endswith("_yaw")]
    amp = np.ptp(clip.joint_qpos[:, [clip.joint_slices()[i].start for i in yaw]], axis=0)
    assert np.all(np.diff(amp) > 0)


def test_manta_wings_flap_symmetrically():
    ch = base_character("manta")
    motion = CharacterMotion.from_clip(GENERATORS["manta"](ch), ch.model)
    data = mujoco.MjData(ch.model)
    left, right = ch.model.body("wing_left3").id, ch.model.body("wing_right3").id
    heights = []
    for q in motion.qpos_frames:
        data.qpos[:] = q
        mujoco.mj_kinematics(ch.model, data)
        heights.append((data.xpos[left, 2], data.xpos[right, 2]))
    heights = np.array(heights)
    np.testing.assert_allclose(heights[:, 0], heights[:, 1], atol=1e-9)
    assert np.ptp(heights[:, 0]) > 0.05  # the tips really go up and down


@pytest.mark.parametrize("preset", ["fish", "manta"])
def test_a_swimmers_clip_asks_for_the_speed_its_stroke_gives_when_tracked(preset):
    """The base swimmer tracking its stroke closely (PD x30, torque limits kept, zero action) in
    MuJoCo's fluid swims within 10% of the clip's root speed, measured from 5 to 20 s; with the
    PD as it is (x1), the stroke lags and the body swims at least 20% slower: what a policy
    gains by tracking the stroke is speed the reference asks for, not speed that ends the
    episode. (Before: the clips asked for the x1 speed, 0.17 and 0.28 m/s, and trained swimmers
    outswam them.)"""
    from common.tasks.shape import references
    from common.tasks.shape.stroke_speed import stroke_speed

    tracked, lagging = stroke_speed(preset), stroke_speed(preset, gain_scale=1.0)
    assert tracked.joint_error_rad < 0.015
    clip, _ = references.task_clip(preset, f"procedural/{preset}", 1.0 / 480.0)  # the shipped .npz the task plays
    np.testing.assert_allclose(clip.root_pos, GENERATORS[preset](base_character(preset)).root_pos, atol=1e-9)
    assert tracked.clip_speed_m_s == pytest.approx((clip.root_pos[-1, 0] - clip.root_pos[0, 0]) / clip.duration_s)
    assert tracked.speed_m_s == pytest.approx(tracked.clip_speed_m_s, rel=0.1), tracked
    assert lagging.speed_m_s < 0.8 * tracked.clip_speed_m_s, lagging


def test_stroke_speed_refuses_what_it_cannot_measure():
    from common.tasks.shape.stroke_speed import stroke_speed
    from learner.tools.stroke_speed import main

    with pytest.raises(ValueError, match="'quadruped' is not a swimmer"):
        stroke_speed("quadruped")
    with pytest.raises(ValueError, match="gain scale 0.5 must be"):
        stroke_speed("fish", gain_scale=0.5)
    with pytest.raises(ValueError, match=r"window \[5.0, 5.5\] s must satisfy"):
        stroke_speed("fish", start_s=5.0, stop_s=5.5)
    with pytest.raises(SystemExit) as exc:
        main(["fish", "--gains", "nan"])
    assert exc.value.code == 2
