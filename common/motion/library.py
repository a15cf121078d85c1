"""`MotionLibrary`: the clips of the manifest, loaded once, played on any character shape.

    lib = MotionLibrary()                              # manifest = common/data/clips.json
    ref = lib.play("humanoid3d_walk", character)       # retargeted to this shape (retarget.py)
    s = ref.state(t)                                   # qpos, qvel, end effectors, COM at t s

Clips come from the canonical `.npz` files under `common/data/clips/` when present
(`morphmimic motion import --all` writes them), else from the raw source files, imported on
first use. Contact phases are computed once per (clip, preset) on the base character and
reused for every shape.

Which clips play on a character as-is: `clips_for("humanoid")` (the 16 DeepMimic clips and
the 8 MASS clips retargeted onto the humanoid, `humanoid/mass_*`), `clips_for("biped")` (the
MASS clips on the biped, `mass/*`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mujoco

from common.motion.clip import Clip, load_clip
from common.motion.cross_skeleton import guess_skeleton, retarget_bvh
from common.motion.errors import ClipError
from common.motion.import_bvh import load_bvh
from common.motion.import_deepmimic import load_deepmimic
from common.motion.mirror import check_symmetric, is_mirrored, mirror_clip, source_id
from common.motion.manifest import DATA_DIR, ClipEntry, Manifest, load_manifest
from common.motion.procedural import GENERATORS
from common.motion.reference import CharacterMotion
from common.motion.retarget import ContactPhases, RetargetConfig, character_feet, contact_phases, play_on

CLIPS_DIR = DATA_DIR / "clips"
LICENSES = {"deepmimic_json": "MIT (DeepMimic, Peng et al.)", "bvh": "Apache-2.0 (MASS, Lee et al.)"}


def import_source(path: str | Path, *, name: str | None = None, label: str = "root", fps: float | None = None,
                  skeleton: str | None = None, license: str = "", character: str | None = None) -> Clip:
    """Import any supported file by its extension: DeepMimic `.txt`/`.json`, `.bvh`
    (skeleton 'mass' or 'cmu', guessed from the file's root joint when None), canonical `.npz`.

    character: for a `.bvh`, the character to import onto: 'biped' (default; the MASS name map)
    or 'humanoid' (cross-skeleton retargeting, `cross_skeleton.retarget_bvh`). Other files are
    bound to their own character and ignore it."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return load_clip(path)
    if suffix in (".txt", ".json"):
        return load_deepmimic(path, fps=fps, name=name, label=label, license=license or "MIT")
    if suffix == ".bvh":
        if skeleton is None:
            skeleton = guess_skeleton(path)
        if character not in (None, "biped"):
            if fps is not None:
                raise ClipError(f"--fps is not supported when retargeting onto {character!r}; the clip keeps the file's rate", path=path)
            return retarget_bvh(path, skeleton=skeleton, character=character, name=name, label=label, license=license)
        return load_bvh(path, skeleton=skeleton, name=name, label=label, fps=fps, license=license)
    raise ClipError(f"unknown motion file type {suffix!r}; expected .txt/.json (DeepMimic), .bvh or .npz", path=path)


def import_entry(entry: ClipEntry, data_dir: Path = DATA_DIR) -> Clip:
    """Import a manifest entry's raw source with its label, loop flag and license; an entry with
    `retarget_from` is retargeted across skeletons onto its `character`."""
    if entry.retarget_from is not None:
        clip = retarget_bvh(data_dir / entry.path, skeleton=entry.retarget_from, character=entry.character, name=entry.id,
                            label=entry.label, license=LICENSES.get(entry.format, ""), loop=entry.loop)
        return clip.with_(extra={**clip.extra, "source_path": entry.path})
    clip = import_source(data_dir / entry.path, name=entry.id, label=entry.label, license=LICENSES.get(entry.format, ""))
    return clip if clip.loop == entry.loop or entry.format != "bvh" else clip.with_(loop=entry.loop)


def clips_for(character: str, manifest: Manifest | None = None) -> list[tuple[str, str]]:
    """`(clip_id, label)` of every manifest clip that plays on `character` as-is, in manifest order.

    For "humanoid": the 16 DeepMimic clips and the 8 MASS clips retargeted onto it
    (`humanoid/mass_*`); for "biped": the MASS clips (`mass/*`). `MotionLibrary().clip(clip_id)`
    loads each. The procedural gaits (`procedural/<preset>`) are not manifest clips.
    Raises ClipError naming an unknown character preset.
    """
    # lazy: start-up time of train --help, which loads common.motion (common.characters adds scipy.optimize)
    from common.characters.presets import PRESETS

    if character not in PRESETS:
        raise ClipError(f"unknown character {character!r}; presets: {', '.join(PRESETS)}")
    manifest = manifest or load_manifest()
    return [(e.id, e.label) for e in manifest.entries if e.character == character]


class MotionLibrary:
    """All clips of a manifest; see module docstring."""

    def __init__(self, manifest: Manifest | None = None, clips_dir: Path = CLIPS_DIR, cfg: RetargetConfig = RetargetConfig()) -> None:
        self.manifest = manifest or load_manifest()
        self.clips_dir = Path(clips_dir)
        self.cfg = cfg
        self._clips: dict[str, Clip] = {}
        self._contacts: dict[tuple[str, str], ContactPhases] = {}
        self._bases: dict[str, object] = {}

    @property
    def ids(self) -> tuple[str, ...]:
        """Manifest clip ids, then the procedural gaits."""
        return tuple(e.id for e in self.manifest.entries) + tuple(f"procedural/{p}" for p in GENERATORS)

    def clip(self, clip_id: str) -> Clip:
        """The canonical clip (cached). Besides the manifest's ids, `procedural/<preset>` is the
        generated gait of the quadruped, fish or manta (procedural.py), and `<id>~mirror` is a
        clip's left-right mirror image (mirror.py)."""
        if clip_id not in self._clips:
            npz = self.clips_dir / f"{clip_id}.npz"
            if is_mirrored(clip_id):
                self._clips[clip_id] = self._mirror(source_id(clip_id))
            elif clip_id.startswith("procedural/"):
                preset = clip_id.split("/", 1)[1]
                if preset not in GENERATORS:
                    raise ClipError(f"no procedural motion for {preset!r}; choose one of {', '.join(GENERATORS)}", path=clip_id)
                self._clips[clip_id] = load_clip(npz) if npz.exists() else GENERATORS[preset](self.base_character(preset))
            else:
                entry = self.manifest.by_id(clip_id)
                self._clips[clip_id] = load_clip(npz) if npz.exists() else import_entry(entry)
        return self._clips[clip_id]

    def _mirror(self, source: str) -> Clip:
        """The mirror image of clip `source`, after checking that its character's rest pose is
        left-right symmetric (`mirror.check_symmetric`)."""
        clip = self.clip(source)
        if not clip.character:
            raise ClipError("a clip bound to no character cannot be mirrored (its rest pose is unknown)", path=source)
        model = self.base_character(clip.character).model
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        check_symmetric(model, data)
        return mirror_clip(clip)

    def base_character(self, preset: str):
        """The preset at its default shape (cached)."""
        if preset not in self._bases:
            # lazy: start-up time of train --help, which loads common.motion (common.characters adds scipy.optimize)
            from common.characters import load_character

            self._bases[preset] = load_character(preset)
        return self._bases[preset]

    def contacts(self, clip_id: str, preset: str) -> ContactPhases:
        """Foot contact phases of a clip on the base character of `preset` (cached)."""
        key = (clip_id, preset)
        if key not in self._contacts:
            base = self.base_character(preset)
            self._contacts[key] = contact_phases(self.clip(clip_id), base.model, character_feet(base), self.cfg)
        return self._contacts[key]

    def retarget_config(self, clip: Clip) -> RetargetConfig:
        """The retargeting settings for one clip: the library's, except that a clip retargeted
        across skeletons (`extra["retarget_from"]`, e.g. `humanoid/mass_balance`) is played with
        the "foot_tracks" root-height rule it was planted with: under "contact_set" a foot joining
        the contact set a few cm up moves the root by that much within a frame (measured on the
        base humanoid: 43 mm on the MASS balance, 38 mm on the pirouette; 4 and 11 mm with
        "foot_tracks"). The other clips keep the library's rule unchanged."""
        if clip.extra.get("retarget_from"):
            return dataclasses.replace(self.cfg, root_height="foot_tracks")
        return self.cfg

    def play(self, clip_id: str, character) -> CharacterMotion:
        """The clip retargeted onto a shaped `common.characters.Character`."""
        clip = self.clip(clip_id)
        if clip.character and clip.character != character.preset:
            raise ClipError(f"clip is for the {clip.character!r} character, not {character.preset!r}", path=clip_id)
        base = self.base_character(character.preset)
        return play_on(clip, character, base, self.retarget_config(clip), self.contacts(clip_id, character.preset))
