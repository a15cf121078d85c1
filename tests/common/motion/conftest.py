"""Shared fixtures: data paths and cached base characters (building one costs ~10 ms)."""

from __future__ import annotations

import functools
import os
from pathlib import Path

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

DATA = Path(__file__).resolve().parents[3] / "common" / "data"
DEEPMIMIC = DATA / "mocap" / "deepmimic" / "motions"
MASS = DATA / "mocap" / "mass" / "motion"
CMU = DATA / "mocap" / "cmu_01_01" / "01_01.bvh"


@functools.lru_cache(maxsize=None)
def base_character(preset: str):
    from common.characters import load_character

    return load_character(preset)


@pytest.fixture(scope="session")
def walk_clip():
    from common.motion.import_deepmimic import load_deepmimic

    return load_deepmimic(DEEPMIMIC / "humanoid3d_walk.txt", label="root/locomotion/walk/forward")
