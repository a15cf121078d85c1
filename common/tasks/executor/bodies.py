"""The executor over body shapes (issue 55 item 1): UniCon's executor (METHOD.md B) on Won & Lee's
shaped humanoids (METHOD.md A), each clip of the library retargeted onto each drawn body.

- `ShapedBodies`: one `ShapedBody` per shape, the humanoid built by `CharacterFactory`
  (C = F(B, b)), its simulated model (compiled by the environment: armatures, actuation,
  projectiles) and Won & Lee's normalization factors of it (`Normalization.from_legs`), kept in
  an LRU per environment (the models are the environment's own, as with projectiles: a step
  or a perturbation writes into them).
- `ShapedReferences`: a clip as the executor tracks it on one body, kept in an LRU per
  (clip, shape) that the environments of a batch share (each entry depends on the clip and the
  shape alone). Built from the clip as prepared once on the base humanoid (`source`: played as
  recorded and low-pass filtered by `ExecutorConfig.reference_filter_hz`), retargeted by
  `retarget.retarget_frames` (root height and stride follow leg length; the stance feet, found
  once per clip on the base, stay on the floor; a foot still below it gets a leg solve), then
  lifted out of the floor with `reference_floor` (per body: a longer arm reaches lower). Its
  frames are made when the scheduler first reads them (`common.motion.lazy_retarget`: the same
  frames bit for bit; a reset reads about a second of a clip, and making every frame of it cost a
  reset some 30 control steps), unless the retargeting needs the whole clip (`lazy_retarget.fits`).

Order: filter, retarget, floor. The base humanoid's own references are filter, floor; the
filter is the costly step (its rotation averaging, 0.2 s on a 5 s take) and does not depend on
the shape, so it runs once per clip, and retargeting after it keeps the stance feet exactly
where the retargeting puts them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import mujoco
import numpy as np

from common.characters import Character, CharacterFactory
from common.lru import Lru
from common.motion.clean import clean_motion
from common.motion.lazy_retarget import FrameRetarget, LazyRetargetedMotion, fits
from common.motion.reference import CharacterMotion
from common.motion.retarget import ContactPhases, RetargetConfig, frame_contact_phases, leg_length_ratio, retarget_frames
from common.tasks.shape.rewards import Normalization


@dataclass(frozen=True)
class ShapedBody:
    """The humanoid of one shape as an environment simulates it."""

    shape: np.ndarray
    """The shape parameters `[P]` (validated, float64)."""
    character: Character
    """The shaped humanoid; `character.model` is the reference model the target frames' kinematics run on."""
    model: mujoco.MjModel
    """The simulated model (`ExecutorEnv._compile` of the character)."""
    ref_data: mujoco.MjData
    """Scratch data of `character.model` for the target frames' kinematics."""
    body_mass: np.ndarray
    body_inertia: np.ndarray
    """`model`'s masses and inertias as compiled, what `ExecutorEnv.scale_mass` scales."""
    norm: Normalization
    """Won & Lee's factors of this body against the base humanoid (leg ratio lbar / lbar0, ...)."""


class ShapedBodies:
    """Bodies by shape for one environment: `get(shape)` builds one (or takes it from the LRU of
    `size`). `compile` makes the simulated model of a character; it runs at once after the
    character is made (a factory's characters share one spec, which describes the latest made)."""

    def __init__(self, factory: CharacterFactory, base: Character, compile: Callable[[Character], mujoco.MjModel],
                 size: int):
        self.factory, self.base, self.compile = factory, base, compile
        self._cache: Lru[ShapedBody] = Lru(size)

    def get(self, shape: np.ndarray) -> ShapedBody:
        shape = np.array(shape, dtype=np.float64)
        return self._cache.get(shape.tobytes(), lambda: self._build(shape))

    def _build(self, shape: np.ndarray) -> ShapedBody:
        ch = self.factory.make(shape)
        model = self.compile(ch)
        norm = Normalization.from_legs(ch.leg_lengths_m, self.base.leg_lengths_m, ch.mass_kg, self.base.mass_kg)
        return ShapedBody(shape, ch, model, mujoco.MjData(ch.model), model.body_mass.copy(), model.body_inertia.copy(),
                          norm)

    def __len__(self) -> int:
        return len(self._cache)


class ShapedReferences:
    """Clips retargeted onto bodies, by (clip, shape) (module docstring). `source(clip_id)`: the
    clip prepared on the base humanoid (`base`), unfloored; `floor`: lift each retargeted frame
    out of the floor (`clean.floor_offsets`)."""

    def __init__(self, source: Callable[[str], CharacterMotion], base: Character, retarget: RetargetConfig,
                 floor: bool, size: int, lazy: bool = True):
        self.source, self.base, self.retarget, self.floor = source, base, retarget, floor
        self.lazy = lazy
        """Make each reference's frames when the scheduler first reads them (`lazy_retarget`; the
        same frames), not all at once when the reference is built."""
        self._cache: Lru[CharacterMotion] = Lru(size)
        self._contacts: dict[str, ContactPhases] = {}

    def get(self, clip_id: str, body: ShapedBody) -> CharacterMotion:
        """The clip `clip_id` on `body`: built on a miss, else the cached motion itself."""
        return self._cache.get((clip_id, body.shape.tobytes()), lambda: self._build(clip_id, body))

    def contacts(self, clip_id: str) -> ContactPhases:
        """The foot contacts of the prepared clip on the base humanoid (computed once per clip)."""
        if clip_id not in self._contacts:
            src = self.source(clip_id)
            self._contacts[clip_id] = frame_contact_phases(src.qpos_frames, src.frames.fps, self.base.model,
                                                           tuple(self.base.foot_geoms), self.retarget)
        return self._contacts[clip_id]

    def forget(self, clip_id: str) -> None:
        """Drop what was built from `clip_id` (its source changed: `ExecutorEnv.register_clip`)."""
        self._contacts.pop(clip_id, None)
        self._cache.clear()

    def _build(self, clip_id: str, body: ShapedBody) -> CharacterMotion:
        src = self.source(clip_id)
        fps, model, contacts = src.frames.fps, body.character.model, self.contacts(clip_id)
        feet, ratio = tuple(self.base.foot_geoms), leg_length_ratio(body.character, self.base)
        if self.lazy and fits(self.retarget, src.frames.loop, contacts):
            # NOTE: the body's reference scratch data: frames are made inside the scheduler's reads,
            # never while the environment's own kinematics loop over it (`reference_kinematics`)
            frames = FrameRetarget(src.qpos_frames, fps, model, feet, ratio, contacts, self.retarget, self.floor,
                                   body.ref_data)
            return LazyRetargetedMotion(src.clip, model, frames)
        return self.build_eager(clip_id, body)

    def build_eager(self, clip_id: str, body: ShapedBody) -> CharacterMotion:
        """The clip on `body` with every frame made at once (`retarget.retarget_frames`, then the
        floor): what a lazy reference's frames equal, bit for bit."""
        src = self.source(clip_id)
        fps, model = src.frames.fps, body.character.model
        qpos = retarget_frames(src.qpos_frames, fps, src.frames.loop, model, tuple(self.base.foot_geoms),
                               leg_length_ratio(body.character, self.base), self.contacts(clip_id), self.retarget)
        return clean_motion(CharacterMotion(src.clip, model, qpos, fps=fps), 0.0, self.floor)

    def __len__(self) -> int:
        return len(self._cache)
