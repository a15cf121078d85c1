"""Issue 4's acceptance test: during contact phases of the walk clips the stance foot stays
within 5 cm of the floor on 20 random shapes of its character."""

import re

import numpy as np
import pytest

from common.motion.import_bvh import load_bvh
from common.motion.import_deepmimic import load_deepmimic
from common.motion.reference import CharacterMotion
from common.motion.retarget import RetargetConfig, contact_phases, play_on
from common.motion.root_height import foot_heights, root_offsets

from .conftest import DEEPMIMIC, MASS, base_character

WALKS = [("humanoid", lambda: load_deepmimic(DEEPMIMIC / "humanoid3d_walk.txt")),
         ("humanoid", lambda: load_deepmimic(DEEPMIMIC / "humanoid3d_zombie_walk.txt")),
         ("biped", lambda: load_bvh(MASS / "walk.bvh"))]
TOLERANCE_M = 0.05


@pytest.mark.parametrize("preset, make_clip", WALKS, ids=["humanoid_walk", "humanoid_zombie_walk", "biped_mass_walk"])
def test_stance_foot_on_the_floor_on_20_random_shapes(preset, make_clip):
    from common.characters import load_character

    clip = make_clip()
    base = base_character(preset)
    contacts = contact_phases(clip, base.model, tuple(base.foot_geoms))
    # Contact phases are real: each foot is on the floor part of the time, and off it part.
    frac = contacts.flags.mean(axis=0)
    assert np.all((frac > 0.3) & (frac < 0.9)), frac
    rng = np.random.default_rng(2024)
    raw_worst = []
    for _ in range(20):
        ch = load_character(preset, shape=base.space.sample(rng), parameterization="random")
        motion = play_on(clip, ch, base, contacts=contacts)
        h, _ = foot_heights(ch.model, motion.qpos_frames, tuple(ch.foot_geoms))
        stance = np.abs(h[contacts.flags])
        assert stance.max() < TOLERANCE_M, (ch.shape, stance.max())
        assert h.min() > -TOLERANCE_M  # the swing foot does not dig in either
        raw = CharacterMotion.from_clip(clip, ch.model)
        h_raw, _ = foot_heights(ch.model, raw.qpos_frames, tuple(ch.foot_geoms))
        raw_worst.append(np.abs(h_raw[contacts.flags]).max())
    # Without retargeting most of these shapes would sink or float: the test has teeth.
    assert np.mean(np.array(raw_worst) > TOLERANCE_M) > 0.5


def test_root_speed_scales_with_leg_length():
    from common.characters import load_character

    clip = load_deepmimic(DEEPMIMIC / "humanoid3d_walk.txt")
    base = base_character("humanoid")
    contacts = contact_phases(clip, base.model, tuple(base.foot_geoms))
    long = load_character("humanoid", shape={"leg_length": 1.6}, parameterization="leg_arm")
    short = load_character("humanoid", shape={"leg_length": 0.6}, parameterization="leg_arm")
    dist = {}
    for name, ch in (("base", base), ("long", long), ("short", short)):
        q = play_on(clip, ch, base, contacts=contacts).qpos_frames
        dist[name] = q[-1, 0] - q[0, 0]
        ratio = np.mean(ch.leg_lengths_m) / np.mean(base.leg_lengths_m)
        assert dist[name] == pytest.approx(ratio * (clip.root_pos[-1, 0] - clip.root_pos[0, 0]), rel=1e-6)
    assert dist["short"] < dist["base"] < dist["long"]


def test_foot_tracks_offset_is_continuous_where_the_contact_set_switches():
    # Two diagonal pairs of a trot: feet 0+3 in contact on frames 0-9, feet 1+2 on 11-19, with
    # foot 1 (a short leg) 12 cm higher than the others when planted.
    h = np.zeros((20, 4))
    h[:, 1] = 0.12
    h[:, 3] = -0.05
    flags = np.zeros((20, 4), dtype=bool)
    flags[:10, [0, 3]] = True
    flags[11:, [1, 2]] = True
    by_set = root_offsets(h, flags, "contact_set")
    by_tracks = root_offsets(h, flags, "foot_tracks")
    assert np.abs(np.diff(by_set)).max() > 0.05  # the root drops by half the difference per frame
    assert np.abs(np.diff(by_tracks)).max() < 1e-9
    # Both put every planted foot at or below the floor (the leg solve lifts the rest).
    for dz in (by_set, by_tracks):
        assert np.all((h + dz[:, None])[flags] <= 1e-12)
    with pytest.raises(ValueError, match=re.escape("'stilts' is not one of contact_set | foot_tracks | contact_smooth")):
        root_offsets(h, flags, "stilts")
    with pytest.raises(ValueError, match="root-height = 'stilts'"):
        RetargetConfig(root_height="stilts")


def test_a_looping_clips_foot_tracks_bridge_the_gap_around_the_loop():
    """A foot planted on frames 3-6 of a 10-frame loop (frame 9 repeats frame 0) at 2 cm, then
    at 8 cm: held at the ends, its track would jump from 8 back to 2 cm where the loop wraps;
    bridged around the loop (period 9 frames) it runs from 8 cm at frame 6 back to 2 cm at frame
    3 + 9, continuous across the wrap. A clip played once keeps the held ends."""
    h = np.zeros((10, 2))
    h[:, 1] = [0.0, 0.0, 0.0, 0.02, 0.04, 0.06, 0.08, 0.0, 0.0, 0.0]
    flags = np.zeros((10, 2), dtype=bool)
    flags[:, 0] = True
    flags[3:7, 1] = True
    held = -root_offsets(h, flags, "foot_tracks", loop=False)
    looped = -root_offsets(h, flags, "foot_tracks", loop=True)
    np.testing.assert_allclose(held[[0, 9]], [0.02, 0.08])
    np.testing.assert_allclose(looped[7:], [0.08 - 0.06 / 6, 0.08 - 0.06 * 2 / 6, 0.08 - 0.06 * 3 / 6], atol=1e-12)
    assert looped[0] == pytest.approx(looped[9]) == pytest.approx(0.05)  # the loop closes
    np.testing.assert_allclose(looped[3:7], h[3:7, 1])


def test_foot_tracks_trot_on_unequal_legs_keeps_its_root_and_feet():
    """The quadruped trot on a tall body whose fr/hl pair is much shorter than its fl/hr pair:
    the contact-set rule drops the root by centimetres within a frame at each switch of pairs;
    foot tracks keep the clip's own 2 cm bob, and the stance feet stay on the floor."""
    from common.characters import load_character
    from common.motion.procedural import quadruped_trot

    base = base_character("quadruped")
    clip = quadruped_trot(base)
    contacts = contact_phases(clip, base.model, tuple(base.foot_geoms))
    shape = {"global_z": 1.4}
    for leg, s in (("fl", 1.2), ("hr", 1.2), ("fr", 0.7), ("hl", 0.7)):
        shape.update({f"{leg}_thigh_z": s, f"{leg}_shank_z": s})
    ch = load_character("quadruped", shape=shape, parameterization="random")
    z = {}
    for rule in ("contact_set", "foot_tracks"):
        motion = play_on(clip, ch, base, RetargetConfig(root_height=rule), contacts)
        z[rule] = motion.qpos_frames[:, 2]
        if rule == "foot_tracks":
            h, _ = foot_heights(ch.model, motion.qpos_frames, tuple(ch.foot_geoms))
            assert np.abs(h[contacts.flags]).max() < TOLERANCE_M
    assert np.abs(np.diff(z["contact_set"])).max() > 0.03
    assert np.abs(np.diff(z["foot_tracks"])).max() < 0.01
    assert np.ptp(z["foot_tracks"]) < 0.03


def test_contact_smooth_lowers_the_root_ahead_of_a_drop_and_rises_at_its_rate():
    """A walk whose stance passes from foot 0 to foot 1 at frame 20 and back at frame 40 with
    no double support (the MASS walk's contacts), foot 1's planted height 12 cm above foot 0's
    (a shorter leg): "contact_set" moves the root by 12 cm within one frame at each switch;
    "contact_smooth" at most 1 cm per frame, never above "contact_set" (no stance foot
    floats), and equal to it away from the switches."""
    n = 60
    h = np.zeros((n, 2))
    h[:, 1] = 0.12
    flags = np.zeros((n, 2), dtype=bool)
    flags[:20, 0] = True
    flags[20:40, 1] = True
    flags[40:, 0] = True
    by_set = root_offsets(h, flags, "contact_set")
    smooth = root_offsets(h, flags, "contact_smooth", max_step=0.01)
    assert np.abs(np.diff(by_set)).max() == pytest.approx(0.12)
    assert np.abs(np.diff(smooth)).max() <= 0.01 + 1e-12
    assert np.all(smooth <= by_set + 1e-12)
    assert np.all((h + smooth[:, None])[flags] <= 1e-12)  # every planted foot at or below the floor
    np.testing.assert_allclose(smooth[:9], 0.0, atol=1e-12)  # until the drop's 11 frames of sinking
    np.testing.assert_allclose(smooth[9:20], -0.01 * np.arange(1, 12), atol=1e-12)  # the long leg bends
    np.testing.assert_allclose(smooth[20:40], -0.12, atol=1e-12)  # the short leg's stance
    np.testing.assert_allclose(smooth[40:52], -0.12 + 0.01 * np.arange(1, 13), atol=1e-12)  # rises after
    np.testing.assert_allclose(smooth[52:], 0.0, atol=1e-12)


def test_lower_envelope_keeps_its_rate_around_the_loop():
    from common.motion.root_height import lower_envelope

    x = np.array([0.0, 0.0, -0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # frame 9 repeats frame 0
    y = lower_envelope(x, 0.02, loop=True)
    np.testing.assert_allclose(y, [-0.01, -0.03, -0.05, -0.03, -0.01, 0.0, 0.0, 0.0, 0.0, -0.01])
    wrap = np.array([-0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.05])
    np.testing.assert_allclose(lower_envelope(wrap, 0.02, loop=True)[[1, 8]], [-0.03, -0.03])
    np.testing.assert_allclose(lower_envelope(wrap, 0.02, loop=False)[[1, 8]], [-0.03, -0.03])
    np.testing.assert_allclose(lower_envelope(x, 1.0), x)  # a loose rate changes nothing


@pytest.mark.parametrize("loop", [False, True])
def test_lower_envelope_is_the_min_plus_cone_envelope(loop):
    """The linear-time passes give y_t = min_j (x_j + s d(t, j)) exactly, d around the loop."""
    from common.motion.root_height import frame_distances, lower_envelope

    rng = np.random.default_rng(7)
    for n in (3, 17, 66):
        x = rng.normal(0.0, 0.05, n)
        if loop:
            x[-1] = x[0]
        brute = np.array([np.min(x + 0.01 * frame_distances(n, t, loop)) for t in range(n)])
        np.testing.assert_allclose(lower_envelope(x, 0.01, loop), brute, atol=1e-12)


def test_bad_smoothing_settings_are_refused():
    h, flags = np.zeros((4, 1)), np.ones((4, 1), dtype=bool)
    with pytest.raises(ValueError, match="contact_smooth rule needs max_step > 0"):
        root_offsets(h, flags, "contact_smooth")
    for field, value in (("root_speed_m_s", 0.0), ("ramp_s", -1.0), ("body_clearance_m", float("nan"))):
        with pytest.raises(ValueError, match=f"{field.replace('_', '-')} = "):
            RetargetConfig(**{field: value})


def test_the_clearance_lift_follows_the_tasks_fall_rule():
    """A task that lets the quadruped's shanks touch does not lift its reference for a shank
    near the floor; under the paper's rule (the preset's) it does."""
    import dataclasses

    from common.tasks.registry import make_env, task_space
    from learner.presets import PRESETS

    task = PRESETS["quadruped"][1].task
    assert task.imitate.shin_contact_is_fall  # Won & Lee's rule: only the feet may touch
    shape = task_space(task).uniform(np.random.default_rng(2019), 6)[5]  # the evaluation's 6th shape

    def root_z(clearance: float, shins_fall: bool) -> np.ndarray:
        env = make_env(dataclasses.replace(task, imitate=dataclasses.replace(
            task.imitate, retarget=dataclasses.replace(task.imitate.retarget, body_clearance_m=clearance),
            shin_contact_is_fall=shins_fall)))
        env.reset(0, shape)
        return env.motion.qpos_frames[:, 2]

    plain = root_z(0.0, False)
    np.testing.assert_array_equal(root_z(0.02, False), plain)
    assert np.max(root_z(0.02, True) - plain) > 0.01  # a hind shank 8 mm above the floor: lifted by 12 mm


def test_contact_smooth_and_the_clearance_lift_on_the_mass_walk():
    """Two of `morphmimic evaluate`'s 300 lower-biped shapes. The third, whose legs differ in
    length: "contact_set" lifts the root by 20 cm within a frame when the long leg takes over;
    "contact_smooth" by at most its rate, and the stance feet stay on the floor. The 37th, a
    tall, narrow body (height x1.49, width x0.69): its retargeted walk brings a shin within 2 cm of
    the floor (into it before the shank box was slimmed), which a 3 cm clearance lift raises to
    3 cm at the cost of a foot floating under 3 cm."""
    import dataclasses

    from common.motion.check import body_clearance
    from common.tasks.registry import make_env, task_space
    from learner.presets import PRESETS

    task = PRESETS["lower_biped"][1].task
    shapes = task_space(task).uniform(np.random.default_rng(2019), 37)

    def motion(rule: str, clearance: float, shape: np.ndarray):
        env = make_env(dataclasses.replace(task, imitate=dataclasses.replace(
            task.imitate, retarget=dataclasses.replace(task.imitate.retarget, root_height=rule, body_clearance_m=clearance))))
        env.reset(0, shape)
        return env, env.motion.qpos_frames

    step = {}
    for rule in ("contact_set", "contact_smooth"):
        env, q = motion(rule, 0.0, shapes[2])
        step[rule] = np.abs(np.diff(q[:, 2])).max()
        h, _ = foot_heights(env.model, q, tuple(env.character.foot_geoms))
        assert h.min() > -0.01, rule
    from common.tasks.shape import references

    flags = references.task_clip("lower_biped", env.clip_id, env.timestep_s)[1].flags
    assert np.abs(h[flags]).max() < 0.01  # contact_smooth: the stance feet on the floor
    assert step["contact_set"] > 0.1
    assert step["contact_smooth"] < 0.5 / 60 + 0.01  # its rate, plus the clip's own bob
    for clearance in (0.0, 0.03):
        env, q = motion("contact_smooth", clearance, shapes[36])
        low, body = body_clearance(env.model, q, np.flatnonzero(~env.allowed_contact))
        assert (low < 0.02) == (clearance == 0.0), (clearance, low, body)
        if clearance:
            assert low >= clearance - 1e-9
            h, _ = foot_heights(env.model, q, tuple(env.character.foot_geoms))
            assert np.abs(h[flags]).max() < 0.03


def test_bend_side_bounds_narrow_only_two_sided_hinges_the_clip_bends_one_way():
    from common.motion.leg_solve import bend_side_bounds

    angles = np.array([[-0.9, 0.0, -0.3, 0.0, 0.2],
                       [0.0, 0.9, 0.4, 0.0, 0.5],
                       [-0.5, 0.4, 0.1, 0.0, 0.0]])
    lo = np.array([-2.4, -2.4, -1.0, -1.0, 0.0])
    hi = np.array([2.4, 2.4, 1.0, 1.0, 2.3])
    new_lo, new_hi = bend_side_bounds(angles, lo, hi)
    # a front knee (never above 0) and a hind knee (never below 0) keep to their side; a joint
    # the clip moves through 0, or never moves, keeps its range; so does a one-sided range.
    np.testing.assert_array_equal(new_lo, [-2.4, 0.0, -1.0, -1.0, 0.0])
    np.testing.assert_array_equal(new_hi, [0.0, 2.4, 1.0, 1.0, 2.3])


def test_quadruped_knees_bend_the_clips_way_and_move_smoothly_on_random_shapes():
    """The leg solve lifts a too-long leg's foot by bending the knee. The quadruped's knees may
    turn either way, and the solve used to pick a way per frame: a knee flipped by 2-3.4 rad
    between two frames on every random shape. Now each knee keeps the clip's side on every
    frame, and with foot tracks (the leg shortened by its track's depth on every frame, swing
    too) no joint moves much more between frames than in the clip on the base body (0.14 rad)."""
    import mujoco

    from common.characters import load_character
    from common.motion.procedural import quadruped_trot

    base = base_character("quadruped")
    clip = quadruped_trot(base)
    contacts = contact_phases(clip, base.model, tuple(base.foot_geoms))
    rng = np.random.default_rng(11)
    worst = {}
    for _ in range(6):
        ch = load_character("quadruped", shape=base.space.sample(rng), parameterization="random")
        m = ch.model
        for rule in ("contact_set", "foot_tracks"):
            q = play_on(clip, ch, base, RetargetConfig(root_height=rule), contacts).qpos_frames
            for leg, sign in (("fl", -1), ("fr", -1), ("hl", 1), ("hr", 1)):
                knee = q[:, m.jnt_qposadr[m.joint(f"{leg}_knee").id]]
                assert np.all(sign * knee >= 0.0), (rule, leg, knee.round(2))
            step = np.zeros(m.nv)
            for k in range(len(q) - 1):
                mujoco.mj_differentiatePos(m, step, 1.0, q[k], q[k + 1])
                worst[rule] = max(worst.get(rule, 0.0), float(np.abs(step[6:]).max()))
            h, _ = foot_heights(m, q, tuple(ch.foot_geoms))
            assert np.abs(h[contacts.flags]).max() < TOLERANCE_M
    assert worst["foot_tracks"] < 0.3, worst


def test_the_lower_bipeds_walk_keeps_every_shank_clear_of_the_floor_on_the_evaluation_shapes():
    """The 300 shapes `morphmimic evaluate` draws (seed 2019), the MASS walk retargeted with
    `contact_smooth` and no lift: with MASS's shank box (11.4 cm deep to 1.6 cm above the ankle)
    the walk put a shank into the floor on 7 short, deep shapes (-14.3 mm at worst), a fall by the
    paper's rule; the slimmer box (`lower_biped.shank_box`) keeps every one 16 mm clear, at MASS's mass."""
    import dataclasses

    from common.characters.presets.biped import parse_mass
    from common.characters.presets.lower_biped import shank_box
    from common.motion.check import body_clearance
    from common.tasks.registry import make_env, task_space
    from learner.presets import PRESETS

    task = PRESETS["lower_biped"][1].task
    task = dataclasses.replace(task, imitate=dataclasses.replace(task.imitate, retarget=dataclasses.replace(
        task.imitate.retarget, root_height="contact_smooth", body_clearance_m=0.0)))
    env = make_env(task)
    lowest = []
    for shape in task_space(task).uniform(np.random.default_rng(2019), 300):
        env.reset(0, shape)
        low, body = body_clearance(env.model, env.motion.qpos_frames, np.flatnonzero(~env.allowed_contact))
        lowest.append((low, body))
    low, body = min(lowest)
    assert low > 0.015, (low, body)
    mass = parse_mass()["TibiaR"]
    slim = shank_box(mass)
    assert slim.mass_kg == mass.mass_kg and slim.half_size[2] < 0.7 * mass.half_size[2]
    from common.characters.character import build_base

    assert build_base("lower_biped").spec.compile().body("TibiaR").mass[0] == pytest.approx(mass.mass_kg)
