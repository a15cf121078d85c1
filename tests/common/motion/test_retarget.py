"""Issue 4's acceptance test: during contact phases of the walk clips the stance foot stays
within 5 cm of the floor on 20 random shapes of its character."""

import numpy as np
import pytest

from common.motion.import_bvh import load_bvh
from common.motion.import_deepmimic import load_deepmimic
from common.motion.reference import CharacterMotion
from common.motion.retarget import contact_phases, foot_heights, play_on

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
