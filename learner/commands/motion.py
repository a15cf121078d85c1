"""`morphmimic motion import|view|check`: the motion library from the shell.

    morphmimic motion import --all --procedural         # manifest + gaits -> common/data/clips/
    morphmimic motion import path/to/clip.bvh --out clips/
    morphmimic motion import path/to/cmu.bvh --character humanoid --out clips/   # cross-skeleton
    morphmimic motion view humanoid3d_walk --shape leg_length=1.6 --parameterization leg_arm --out walk.png
    morphmimic motion check --all                       # one line per clip
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, ClassVar, Literal, get_args

import numpy as np
import tyro

from common.config_limits import SEED, Limit, above, at_least, check_limits, validated
from common.motion import bandai
from common.motion.check import check_motion
from common.motion.cross_skeleton import naive_clip
from common.motion.errors import ClipError
from common.motion.library import CLIPS_DIR, MotionLibrary, import_entry, import_source
from common.motion.manifest import DATA_DIR
from common.motion.mirror import MIRROR_SUFFIX, source_id
from common.motion.procedural import GENERATORS
from common.motion.reference import CharacterMotion
from common.motion.retarget import character_feet, contact_phases, play_on
from common.motion.root_height import ROOT_HEIGHT_RULES
from common.tasks.executor.config import ExecutorConfig
from learner.cli import dispatch
from learner.cli_options import parse_options
from learner.progress import Progress


RootHeightRule = Literal["contact_set", "foot_tracks", "contact_smooth"]
assert get_args(RootHeightRule) == ROOT_HEIGHT_RULES


def _parse_shape(items: tuple[str, ...]) -> dict[str, float] | None:
    """`name=value` items as a shape; ValueError naming the first item that is not one."""
    if not items:
        return None
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            out[name] = float(value)
        except ValueError:
            raise ValueError(f"--shape expects name=value, got {item!r}") from None
        if not sep:
            raise ValueError(f"--shape expects name=value, got {item!r}")
    return out


@validated
@dataclass
class ImportOptions:
    sources: tyro.conf.Positional[tuple[str, ...]] = ()
    """Motion files (.txt/.json DeepMimic, .bvh)."""
    all: bool = False
    """Every clip of common/data/clips.json."""
    procedural: bool = False
    """Also write the quadruped/fish/manta gaits."""
    out: str | None = None
    """Output directory (default common/data/clips/)."""
    fps: float | None = None
    """Resample to this rate in Hz (default: the file's)."""
    skeleton: Literal["mass", "cmu"] | None = None
    """BVH name map (default: guessed)."""
    character: str | None = None
    """Import a BVH onto this character: biped (default) or humanoid (cross-skeleton retargeting)."""
    label: str = "root"
    """Hierarchical class label for files given by path."""
    bandai: str | None = None
    """Convert the Bandai Namco datasets below this directory onto the humanoid (common/motion/bandai.py)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"fps": above(0)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


@validated
@dataclass(kw_only=True)
class _OnACharacter:
    """Options of the commands that play a clip on a (shaped) character."""

    character: str | None = None
    """Preset (default: the clip's own character)."""
    parameterization: str = "random"
    """Shape parameterization of the preset."""
    shape: Annotated[tuple[str, ...], tyro.conf.UseAppendAction] = ()
    """name=value shape factor (repeatable)."""
    random_shape: Annotated[int | None, tyro.conf.arg(metavar="SEED")] = None
    """A random shape from this seed."""

    LIMITS: ClassVar[dict[str, Limit]] = {"random_shape": SEED}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)
        _parse_shape(self.shape)


@validated
@dataclass(kw_only=True)
class ViewOptions(_OnACharacter):
    clip: tyro.conf.Positional[str]
    """Manifest id (e.g. humanoid3d_walk) or a motion file."""
    out: str
    """Output .png (strip) or .gif/.mp4."""
    frames: int = 6
    """Poses in a PNG strip."""
    fps: float = 30.0
    """Animation frame rate."""
    seconds: float | None = None
    """Time span shown (default the clip; longer loops)."""
    retarget: bool = True
    """Retarget the clip onto the character (--no-retarget: play it as recorded)."""

    LIMITS: ClassVar[dict[str, Limit]] = {**_OnACharacter.LIMITS, "frames": at_least(1), "fps": above(0),
                                          "seconds": above(0)}


@validated
@dataclass(kw_only=True)
class CheckOptions(_OnACharacter):
    clips: tyro.conf.Positional[tuple[str, ...]] = ()
    """Manifest ids or motion files."""
    all: bool = False
    """Every clip of the manifest."""
    root_height: RootHeightRule | None = None
    """Root-height rule of the retargeting (default: the library's, contact_set; foot_tracks for
    clips retargeted across skeletons)."""
    filter_hz: float = 7.0
    """Cut-off (Hz) of the cleaning the second line per clip reports after (the executor's
    `reference_filter_hz`; 0: no filter)."""
    floor: bool = True
    """The cleaning the second line reports after lifts every frame out of the floor (the
    executor's `reference_floor`)."""

    LIMITS: ClassVar[dict[str, Limit]] = {**_OnACharacter.LIMITS, "filter_hz": at_least(0, False)}


def _resolve(lib, spec: str, character: str | None = None):
    """A clip from a manifest id or a file path (a BVH imported onto `character` when given)."""
    if source_id(spec) in lib.ids:
        return lib.clip(spec)
    if Path(spec).exists():
        return import_source(spec, character=character)
    raise ClipError(f"neither a clip id of the manifest nor a file; ids: {', '.join(lib.ids)} (each also as "
                    f"<id>{MIRROR_SUFFIX}, its mirror image)", path=spec)


def _character(preset: str, args):
    # lazy: start-up time of morphmimic motion --help (common.characters adds scipy.optimize)
    from common.characters import load_character

    shape = _parse_shape(args.shape)
    if args.random_shape is not None:
        base = load_character(preset, parameterization=args.parameterization)
        shape = base.space.sample(np.random.default_rng(args.random_shape))
    return load_character(preset, shape=shape, parameterization=args.parameterization)


def cmd_import(args) -> int:
    out_dir = Path(args.out) if args.out else CLIPS_DIR
    if args.bandai:  # the Bandai Namco takes onto the humanoid + their manifest entries
        bar_for = lambda n: Progress("[motion import] bandai", n, "takes")  # noqa: E731
        return 1 if bandai.import_bandai(args.bandai, args.out, bar_for=bar_for)[1] else 0
    jobs = []
    if args.all:
        lib = MotionLibrary()
        jobs += [(e.id, lambda e=e: import_entry(e)) for e in lib.manifest.entries]
    if args.procedural:
        # lazy: start-up time of morphmimic motion --help (common.characters adds scipy.optimize)
        from common.characters import load_character

        jobs += [(f"procedural/{p}", lambda p=p, g=g: g(load_character(p))) for p, g in GENERATORS.items()]
    for src in args.sources:
        jobs.append((Path(src).stem, lambda s=src: import_source(s, fps=args.fps, skeleton=args.skeleton, label=args.label,
                                                                 character=args.character)))
    if not jobs:
        print("morphmimic motion import: give source files, --all or --procedural", file=sys.stderr)
        return 2
    with Progress("[motion import]", len(jobs), "clips") as bar:
        for clip_id, make in jobs:
            clip = make()
            path = clip.save(out_dir / f"{clip_id}.npz")
            try:
                path = path.relative_to(Path.cwd())
            except ValueError:
                pass
            bar.write(f"{path}: {clip.num_frames} frames at {clip.fps:.1f} Hz ({clip.duration_s:.2f} s), "
                      f"{len(clip.joint_names)} joints for {clip.character!r}, label {clip.label}")
            bar.update()
    return 0


def cmd_view(args) -> int:
    lib = MotionLibrary()
    clip = _resolve(lib, args.clip, args.character)
    preset = args.character or clip.character
    ch = _character(preset, args)
    motion = play_on(clip, ch, lib.base_character(preset)) if args.retarget else None
    if motion is None:
        motion = CharacterMotion.from_clip(clip, ch.model, tuple(ch.end_effector_bodies))
    # lazy: start-up time of morphmimic motion --help (imageio)
    from common.motion.view import write_animation, write_strip

    out = Path(args.out)
    if out.suffix.lower() == ".png":
        write_strip(motion, out, n_frames=args.frames, seconds=args.seconds)
    else:
        write_animation(motion, out, fps=args.fps, seconds=args.seconds)
    print(f"{out}: {clip.name} on {ch.summary()}")
    return 0


def _raw_clip(clip):
    """What `check` compares a clip with: the clip as recorded, or for a clip retargeted across
    skeletons (`extra["retarget_from"]`) its source BVH copied naively onto the same character
    (local rotations, no rest-pose correction, root as recorded: `cross_skeleton.naive_clip`)."""
    skeleton, source = clip.extra.get("retarget_from"), clip.extra.get("source_path")
    if not skeleton or not source:
        return clip
    path = DATA_DIR / source if (DATA_DIR / source).exists() else Path(source)
    if not path.exists():  # a shipped clip whose source is not in the repository (Bandai Namco)
        return clip
    if not path.exists():  # a shipped clip whose source is not in the repository (Bandai Namco)
        return clip
    return naive_clip(path, skeleton=skeleton, character=clip.character)


CONTROL_HZ = 60.0
"""The executor's control rate: the grid `cleaning_line` measures a clip on."""
EXECUTOR_CHARACTER = "humanoid"
"""The character the executor tracks clips on: `check` adds `cleaning_line` for its clips."""


def cleaning_line(clip, model, filter_hz: float, floor: bool) -> str:
    """The clip as the executor tracks it (played as recorded on `model`, once through), before
    and after its cleaning (`common.motion.clean`: filter at `filter_hz`, `floor`), on the
    executor's 60 Hz control grid: share of steps with a DOF outside its PD target range (and
    outside the MimicKit/PHC widened one), the largest one-step change of the target joint
    velocities against the joint-velocity term's tolerance and the share of steps above it, and
    the lowest geom's height (median, worst, share of steps below the floor)."""
    # lazy: start-up time of motion --help (common.motion.clean adds scipy.optimize)
    from common.motion.clean import clean_motion, reference_stats

    ex = ExecutorConfig()
    tolerance = float(np.log(1.0 / ex.alpha) / ex.reward_scales[4])
    raw = CharacterMotion.from_clip(clip.with_(loop=False), model)
    clean = clean_motion(raw, filter_hz, floor)
    what = ", ".join([f"filter {filter_hz:g} Hz"] * bool(filter_hz) + ["floor"] * floor) or "nothing"
    return (f"{'':<2}executor reference at {CONTROL_HZ:g} Hz: raw {reference_stats(raw, 1 / CONTROL_HZ, tolerance).line()}\n"
            f"{'':<2}cleaned ({what}){'':<8} {reference_stats(clean, 1 / CONTROL_HZ, tolerance).line()}")


def cmd_check(args) -> int:
    lib = MotionLibrary()
    specs = list(args.clips) + (list(lib.ids) if args.all else [])
    specs = list(dict.fromkeys(specs))
    if not specs:
        print("morphmimic motion check: give clip ids / files or --all", file=sys.stderr)
        return 2
    failed = 0
    print("clip, character, rate, length; feet: deepest below floor (pen), lower foot above it in contact phases "
          "(float), lower foot above it over every frame (low: max, mean), as recorded (for a clip retargeted across "
          "skeletons: its source copied naively) -> retargeted; frames with both feet up; the retargeted root height's "
          "range over the clip and largest step between frames; (frame, DOF) pairs outside the joint range. Then, for a "
          "humanoid clip, the clip as the executor tracks it, raw and cleaned: steps with a DOF outside its PD target "
          "range (widened: as MimicKit/PHC), the largest one-step change of the target joint velocities ((rad/s)^2, against the "
          "joint-velocity term's tolerance) and the share of steps above it, the lowest geom's height (median, worst, "
          "share of steps below the floor)")
    for spec in specs:
        try:
            clip = _resolve(lib, spec, args.character)
            preset = args.character or clip.character
            ch = _character(preset, args) if (args.shape or args.random_shape is not None) else lib.base_character(preset)
            base = lib.base_character(preset)
            feet = character_feet(ch)
            cfg = lib.retarget_config(clip)
            cfg = dataclasses.replace(cfg, root_height=args.root_height) if args.root_height else cfg
            contacts = contact_phases(clip, base.model, feet, cfg) if feet else None
            flags = None if contacts is None else contacts.flags
            motion = play_on(clip, ch, base, cfg, contacts)
            raw_clip = _raw_clip(clip)
            raw_flags = flags if raw_clip.num_frames == clip.num_frames else None
            raw = check_motion(CharacterMotion.from_clip(raw_clip, ch.model), feet, raw_flags)
            print(check_motion(motion, feet, flags).line(raw))
            if preset == EXECUTOR_CHARACTER:
                print(cleaning_line(clip, ch.model, args.filter_hz, args.floor))
        except ClipError as exc:
            failed += 1
            print(f"{spec:<26} ERROR {exc}")
    return 1 if failed else 0


SUBCOMMANDS = {
    "import": (ImportOptions, cmd_import, "convert DeepMimic JSON / BVH to canonical .npz clips"),
    "view": (ViewOptions, cmd_view, "render a clip kinematically to a PNG strip (.png) or animation (.gif/.mp4)"),
    "check": (CheckOptions, cmd_check, "per clip: feet vs floor, joint-range violations, rate, length; the executor's "
                                       "reference before and after cleaning"),
}


def _runner(name: str):
    """`main(argv)` of one subcommand: its options parsed, then run; a ClipError is one line, exit 1."""
    options, run, text = SUBCOMMANDS[name]
    prog = f"morphmimic motion {name}"

    def main(argv: list[str]) -> int:
        args = parse_options(options, argv, prog=prog, description=text)
        try:
            return run(args)
        except ClipError as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            return 1

    return main


def main(argv: list[str]) -> int:
    table = {name: (_runner(name), text) for name, (_, _, text) in SUBCOMMANDS.items()}
    return dispatch("morphmimic motion", "subcommand", table, argv)
