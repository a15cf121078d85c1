"""The Bandai Namco Research motion datasets on the DeepMimic humanoid: conversion and labels.

    morphmimic motion import --bandai /path/to/bandai_namco

reads every `*/data/*.bvh` below the folder (the upstream layout: `dataset-1/`, `dataset-2*/`,
each with `cfg/content_label.txt`, `cfg/style_label.txt` and `X.json` = {"content": i, "style":
j} beside `X.bvh`), retargets each take onto the humanoid (`cross_skeleton.retarget_bvh` with the
'bandai' skeleton map: rotated rest frames, root scaled by the hip-height ratio, feet planted),
writes `common/data/clips/humanoid/bandai/<take>.npz` (float32, compressed) and puts one
manifest entry per take into `common/data/clips.json`. The project reads only those files at run
time; the BVH folder is needed for conversion alone.

Labels: `root/bandai/<content>/<style>` (UniCon 2020, METHOD.md B: the motion balancer walks the
label tree, so below the one `bandai` node every content weighs the same and, within a content,
every style). Content and style come from the take's JSON and the dataset's label files; the
file name (`dataset-N_{content}_{style}_{take}`) must agree, else the take fails.

License: CC BY-NC 4.0 (non-commercial use, with attribution to Bandai Namco Research Inc.);
everything made from these clips, checkpoints trained on them included, carries the same terms
(`common/data/clips/humanoid/bandai/README.md`).
"""

from __future__ import annotations

import contextlib
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, ContextManager

from common.motion.bvh import parse_bvh
from common.motion.clip import Clip
from common.motion.cross_skeleton import retarget_bvh
from common.motion.errors import ClipError
from common.motion.library import CLIPS_DIR
from common.motion.manifest import CLIPS_JSON

ID_PREFIX = "humanoid/bandai/"
"""Manifest ids (and paths below `common/data/clips/`) of the converted takes."""
LABEL_PREFIX = "root/bandai"
LICENSE = "CC BY-NC 4.0 (Bandai Namco Research Inc., Bandai-Namco-Research-Motiondataset)"


@dataclass(frozen=True)
class Take:
    """One BVH take of the dataset with its two-level label."""

    path: Path
    dataset: str
    """The dataset folder's name (`dataset-1`, `dataset-2-pool`)."""
    content: str
    style: str

    @property
    def stem(self) -> str:
        return self.path.stem

    @property
    def clip_id(self) -> str:
        return ID_PREFIX + self.stem

    @property
    def label(self) -> str:
        return f"{LABEL_PREFIX}/{self.content}/{self.style}"

    @property
    def source(self) -> str:
        """The BVH's path below the dataset root (provenance, recorded in the clip and manifest)."""
        return f"bandai_namco/{self.dataset}/data/{self.path.name}"


def _labels(cfg: Path, kind: str, prefix: str) -> list[str]:
    path = cfg / f"{kind}_label.txt"
    try:
        lines = [ln.strip() for ln in path.read_text().splitlines() if ln.strip()]
    except OSError as exc:
        raise ClipError(f"cannot read the {kind} labels ({exc})", path=path) from exc
    return [ln[len(prefix) + 1:] if ln.startswith(prefix + "_") else ln for ln in lines]


def find_takes(root: str | Path) -> tuple[list[Take], list[tuple[Path, str]]]:
    """(takes, failures) below `root`: every `<dataset>/data/*.bvh`, labelled from its JSON via
    `<dataset>/cfg/{content,style}_label.txt` and checked against its file name; a take whose
    label cannot be read or disagrees is a failure `(path, reason)`."""
    root = Path(root)
    bvhs = sorted(root.glob("*/data/*.bvh"))
    if not bvhs:
        raise ClipError("no <dataset>/data/*.bvh below this folder (the Bandai Namco layout)", path=root)
    takes, failures = [], []
    cache: dict[Path, tuple[list[str], list[str]]] = {}
    for bvh in bvhs:
        dataset_dir = bvh.parent.parent
        try:
            prefix = bvh.stem.split("_")[0]
            if dataset_dir not in cache:
                cfg = dataset_dir / "cfg"
                cache[dataset_dir] = (_labels(cfg, "content", prefix), _labels(cfg, "style", prefix))
            contents, styles = cache[dataset_dir]
            meta = json.loads(bvh.with_suffix(".json").read_text())
            content, style = contents[int(meta["content"])], styles[int(meta["style"])]
            parts = bvh.stem.split("_")
            if len(parts) != 4 or (parts[1], parts[2]) != (content, style):
                raise ClipError(f"the JSON says content {content!r}, style {style!r}; the file name says {parts[1:3]}", path=bvh)
            takes.append(Take(bvh, dataset_dir.name, content, style))
        except (ClipError, OSError, ValueError, KeyError, IndexError, TypeError) as exc:
            failures.append((bvh, f"label: {exc}"))
    return takes, failures


def convert_take(take: Take) -> Clip:
    """One take retargeted onto the humanoid, labelled, with its provenance in `extra`."""
    clip = retarget_bvh(parse_bvh(take.path), skeleton="bandai", character="humanoid", name=take.clip_id,
                        label=take.label, license=LICENSE, loop=False)
    return clip.with_(source=f"bvh:{take.path.name}", extra={**clip.extra, "source_path": take.source,
                                                              "content": take.content, "style": take.style})


def manifest_entry(take: Take, clip: Clip) -> dict:
    """The clips.json entry of a converted take: the shipped `.npz` is its source."""
    return {"id": take.clip_id, "path": f"clips/{take.clip_id}.npz", "label": take.label, "format": "npz",
            "fps": round(clip.fps, 3), "frames": clip.num_frames, "duration_s": round(clip.duration_s, 3), "loop": None,
            "character": "humanoid", "source": take.source, "license": "CC BY-NC 4.0"}


def write_manifest(entries: list[dict], path: Path = CLIPS_JSON) -> None:
    """Replace the manifest's Bandai entries (ids under `ID_PREFIX`) by `entries`, keeping the others."""
    doc = json.loads(path.read_text())
    doc["clips"] = [c for c in doc["clips"] if not str(c.get("id", "")).startswith(ID_PREFIX)] + entries
    path.write_text(json.dumps(doc, indent=1) + "\n")


def import_bandai(root: str | Path, out_dir: str | Path | None = None, manifest: str | Path | None = CLIPS_JSON,
                  log=print, bar_for: Callable[[int], ContextManager[Any]] | None = None) -> tuple[list[Clip], list[tuple[Path, str]]]:
    """Convert every take below `root` (module docstring) into `out_dir` (default
    `common/data/clips/`) as `humanoid/bandai/<take>.npz`, float32 compressed, and put their
    entries into `manifest` (None: leave it). Returns (clips, failures); a take that fails is
    reported with its reason and left out, the others are still written. `bar_for(n)`: a
    progress bar for n takes (a context whose value has `update()`; the command's
    `learner.progress.Progress`), advanced per take, which then replaces the per-take lines."""
    out_dir = Path(out_dir) if out_dir else CLIPS_DIR
    takes, failures = find_takes(root)
    clips, entries = [], []
    start = time.monotonic()
    with (bar_for(len(takes)) if bar_for else contextlib.nullcontext()) as bar:
        for k, take in enumerate(takes):
            try:
                clip = convert_take(take)
            except ClipError as exc:
                failures.append((take.path, str(exc)))
                log(f"FAILED {take.stem}: {exc}")
                continue
            finally:
                if bar is not None:
                    bar.update()
            clip.save(out_dir / f"{take.clip_id}.npz", compact=True)
            clips.append(clip)
            entries.append(manifest_entry(take, clip))
            if bar is None:
                log(f"[{k + 1}/{len(takes)} {time.monotonic() - start:.0f} s] {take.clip_id}: {clip.num_frames} frames, {take.label}")
    if manifest is not None:
        write_manifest(entries, Path(manifest))
    log(f"{len(clips)} clips converted, {sum(c.num_frames for c in clips)} frames; {len(failures)} failed")
    for path, reason in failures:
        log(f"  {path.name}: {reason}")
    return clips, failures
