"""Dataset manifest: every clip with its hierarchical label, and UniCon's train/test split.

Labels are paths `root/<major>/<minor>/...` (UniCon, Wang et al. 2020): the motion balancer
walks this tree choosing each child with equal probability. The manifest starts from
`common/data/clips.json`.

Each entry: `id`, `path` (the raw source, relative to `common/data/`), `label`, `format`
(`deepmimic_json` | `bvh` | `npz`: a shipped canonical clip whose raw source is not in the
repository, e.g. the Bandai Namco takes, `common.motion.bandai`), `fps`, `frames`, optional `loop` ("wrap"), and two optional fields
for clips played on another character than their source's own:
- `character`: the character preset the clip plays on as-is; default the format's own
  (`deepmimic_json` -> humanoid, `bvh` -> biped, `NATIVE_CHARACTER`);
- `retarget_from`: the source skeleton of a BVH retargeted across skeletons onto `character`
  (`mass` | `cmu`, `common.motion.cross_skeleton`), e.g. the MASS clips on the humanoid.

Split (UniCon's evaluation protocol: "80/20 of frames; rare classes go to the test set first"):
the reconstruction implemented here, configurable by `test_fraction` and `class_depth`:
1. a clip's class is its label cut to `class_depth` levels below `root` (default: the full label);
2. classes are ordered by their total frame count, rarest first; ties are broken by a
   seeded shuffle, so a seed fixes the split;
3. walking that order, whole clips (in seeded order within a class) move to the test set while
   the test set is below `test_fraction` of all frames; a clip that would overshoot the target
   by more than it would undershoot is skipped, so the test share lands near the target.
Frames are counted at one common rate (`SPLIT_FPS`, i.e. by duration): UniCon's dataset has one
frame rate, this one mixes 16-120 Hz captures, and counting raw frames made a 120 Hz MASS clip
weigh 4-8 times a DeepMimic clip of the same length (all 16 DeepMimic clips counted as "rare").
"""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common.motion.cross_skeleton import SOURCE_SKELETONS, TARGETS
from common.motion.errors import ClipError

DATA_DIR = Path(__file__).resolve().parent.parent / "data"
CLIPS_JSON = DATA_DIR / "clips.json"
NATIVE_CHARACTER = {"deepmimic_json": "humanoid", "bvh": "biped"}
"""The character a source format's clips play on without retargeting."""
SPLIT_FPS = 60.0
"""The common rate at which `unicon_split` counts a clip's frames (see module docstring)."""


@dataclass(frozen=True)
class ClipEntry:
    """One clip of the manifest: `path` is relative to `common/data/`."""

    id: str
    path: str
    label: str
    format: str
    fps: float
    frames: int
    loop: bool
    character: str = ""
    """The character preset the clip plays on as-is (`humanoid`, `biped`)."""
    retarget_from: str | None = None
    """Source skeleton (`mass`, `cmu`) of a BVH retargeted onto `character`; None if not retargeted."""

    @property
    def label_parts(self) -> tuple[str, ...]:
        """('root', 'locomotion', 'walk', 'forward')."""
        return tuple(self.label.split("/"))

    @property
    def duration_s(self) -> float:
        """(frames - 1) / fps, as `Clip.duration_s` of the clip once loaded (to a fraction of a
        millisecond: an import may resample); 0 for a clip without a rate."""
        return (self.frames - 1) / self.fps if self.fps > 0 else 0.0

    @property
    def split_frames(self) -> float:
        """The clip's length in frames at SPLIT_FPS (its duration x 60)."""
        return self.frames / self.fps * SPLIT_FPS if self.fps > 0 else float(self.frames)

    def class_at(self, depth: int | None) -> str:
        """The label cut to `depth` levels below root (None: the whole label)."""
        parts = self.label_parts
        return "/".join(parts if depth is None else parts[: depth + 1])


@dataclass(frozen=True)
class Manifest:
    """All clips of a dataset."""

    entries: tuple[ClipEntry, ...]

    @property
    def total_frames(self) -> int:
        return sum(e.frames for e in self.entries)

    def by_id(self, clip_id: str) -> ClipEntry:
        for e in self.entries:
            if e.id == clip_id:
                return e
        raise KeyError(f"no clip {clip_id!r}; known: {', '.join(e.id for e in self.entries)}")

    def label_tree(self) -> dict:
        """Nested dict of labels: {'root': {'locomotion': {'walk': {'forward': {'_clips': [ids]}}}}}.

        A node's clips are under the key `_clips`; the motion balancer (sampler/) walks it.
        """
        tree: dict = {}
        for e in self.entries:
            node = tree
            for part in e.label_parts:
                node = node.setdefault(part, {})
            node.setdefault("_clips", []).append(e.id)
        return tree

    def frames_per_class(self, depth: int | None = None) -> dict[str, int]:
        """{class: total frames} at a label depth."""
        out: dict[str, int] = defaultdict(int)
        for e in self.entries:
            out[e.class_at(depth)] += e.frames
        return dict(out)


def load_manifest(path: str | Path = CLIPS_JSON) -> Manifest:
    """Read a clips.json-style manifest; ClipError names a bad entry and the missing field."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
        raw = doc["clips"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ClipError(f'expected JSON with a "clips" list ({exc})', path=path) from exc
    entries = []
    for k, c in enumerate(raw):
        try:
            label = str(c["label"])
            if not label.startswith("root"):
                raise ClipError(f"label {label!r} must start with 'root/'", path=path, joint=c.get("id"))
            fmt = str(c["format"])
            character, retarget_from = _character_fields(c, k, fmt, path)
            entries.append(ClipEntry(id=str(c["id"]), path=str(c["path"]), label=label, format=fmt,
                                     fps=float(c["fps"]), frames=int(c["frames"]), loop=c.get("loop") == "wrap",
                                     character=character, retarget_from=retarget_from))
        except ClipError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise ClipError(f"clip entry {k} lacks or has a bad field ({exc}); needs id, path, label, format, fps, frames", path=path) from exc
    ids = [e.id for e in entries]
    if len(set(ids)) != len(ids):
        raise ClipError(f"duplicate clip ids: {sorted({i for i in ids if ids.count(i) > 1})}", path=path)
    return Manifest(tuple(entries))


def _character_fields(c: dict, k: int, fmt: str, path: Path) -> tuple[str, str | None]:
    """(character, retarget_from) of a manifest entry, validated (module docstring)."""
    where = f"clip entry {k} ({c.get('id')!r})"
    native = NATIVE_CHARACTER.get(fmt, "")
    retarget_from = c.get("retarget_from")
    character = c.get("character", native)
    if not isinstance(character, str):
        raise ClipError(f"{where}: character {character!r} must be a character preset name", path=path)
    if retarget_from is None:
        if native and character != native:
            raise ClipError(f"{where}: character {character!r} is not what a {fmt!r} clip plays on ({native!r}); "
                            f"a BVH for another character needs retarget_from", path=path)
        return character, None
    if not isinstance(retarget_from, str) or retarget_from not in SOURCE_SKELETONS:
        raise ClipError(f"{where}: retarget_from {retarget_from!r} is not a known source skeleton; choose one of "
                        f"{', '.join(map(repr, SOURCE_SKELETONS))}", path=path)
    if fmt != "bvh":
        raise ClipError(f"{where}: retarget_from {retarget_from!r} needs format 'bvh', not {fmt!r}", path=path)
    if character not in TARGETS:
        raise ClipError(f"{where}: character {character!r} is not a retargeting target; choose one of "
                        f"{', '.join(map(repr, TARGETS))}", path=path)
    return character, retarget_from


@dataclass(frozen=True)
class Split:
    """A train/test split of clip ids."""

    train: tuple[str, ...]
    test: tuple[str, ...]
    seed: int
    test_fraction_frames: float
    """The share of frames that landed in the test set."""


def unicon_split(manifest: Manifest, *, seed: int = 0, test_fraction: float = 0.2, class_depth: int | None = None) -> Split:
    """Category-aware split, rarest classes to the test set first (see module docstring)."""
    if not 0.0 < test_fraction < 1.0:
        raise ValueError(f"test_fraction must be in (0, 1), got {test_fraction}")
    rng = np.random.default_rng(seed)
    classes: dict[str, list[ClipEntry]] = defaultdict(list)
    for e in manifest.entries:
        classes[e.class_at(class_depth)].append(e)
    names = sorted(classes)
    tiebreak = dict(zip(names, rng.permutation(len(names))))
    order = sorted(names, key=lambda c: (sum(e.split_frames for e in classes[c]), tiebreak[c]))
    total = sum(e.split_frames for e in manifest.entries)
    target = test_fraction * total
    test: list[str] = []
    test_frames = 0.0
    for cls in order:
        members = sorted(classes[cls], key=lambda e: e.id)
        for i in rng.permutation(len(members)):
            e = members[i]
            if test_frames >= target:
                break
            # NOTE: take the clip only if that lands nearer the target than leaving it out.
            if abs(test_frames + e.split_frames - target) <= abs(test_frames - target):
                test.append(e.id)
                test_frames += e.split_frames
    train = tuple(e.id for e in manifest.entries if e.id not in test)
    return Split(train=train, test=tuple(sorted(test)), seed=seed, test_fraction_frames=test_frames / total)


def unicon_take_split(manifest: Manifest, *, seed: int = 0, test_fraction: float = 0.2) -> Split:
    """Per-class split by takes, for a library whose classes hold several takes of one motion
    (the Bandai Namco content x style pairs, labels `root/bandai/<content>/<style>`).

    UniCon 2020 (METHOD.md B, "Evaluation": split by category, 80/20, rare classes go to the test
    set first), applied per class (a clip's whole label) instead of over frames:
    - a class with a single take goes to the test set (the rare-classes-first rule at its limit:
      a motion seen once is kept for evaluating generalization);
    - of a class with n >= 2 takes, max(1, round(test_fraction * n)) takes chosen by a seeded
      permutation go to the test set, the rest to training: every such class is both trained
      on and tested on unseen takes of it (4 takes -> 1 held out, 2 -> 1).
    A seed fixes the split; `test_fraction_frames` reports the share of frames (at SPLIT_FPS)
    that landed in the test set."""
    if not 0.0 < test_fraction < 1.0:
        raise ValueError(f"test_fraction must be in (0, 1), got {test_fraction}")
    rng = np.random.default_rng(seed)
    classes: dict[str, list[ClipEntry]] = defaultdict(list)
    for e in manifest.entries:
        classes[e.label].append(e)
    test: list[str] = []
    for cls in sorted(classes):
        members = sorted(classes[cls], key=lambda e: e.id)
        held = len(members) if len(members) == 1 else max(1, round(test_fraction * len(members)))
        test += [members[i].id for i in rng.permutation(len(members))[:held]]
    chosen = set(test)
    total = sum(e.split_frames for e in manifest.entries)
    test_frames = sum(e.split_frames for e in manifest.entries if e.id in chosen)
    train = tuple(e.id for e in manifest.entries if e.id not in chosen)
    return Split(train=train, test=tuple(sorted(test)), seed=seed, test_fraction_frames=test_frames / total if total else 0.0)
