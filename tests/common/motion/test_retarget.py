"""Issue 4's acceptance test: during contact phases of the walk clips the stance foot stays
within 5 cm of the floor on 20 random shapes of its character."""

import re

import numpy as np
import pytest

from common.motion.import_bvh import load_bvh
from common.motion.import_deepmimic import load_deepmimic
from common.motion.reference import CharacterMotion
from common.motion.retarget import RetargetConfig, contact_phases, foot_heights, play_on, root_offsets

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
    with pytest.raises(ValueError, match=re.escape("'stilts' is not one of contact_set | foot_tracks")):
        root_offsets(h, flags, "stilts")
    with pytest.raises(ValueError, match="root_height 'stilts'"):
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
