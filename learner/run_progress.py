"""`<run>/progress.json`: where the run is, rewritten after every iteration.

A checkpoint is written every `checkpoint_every` iterations; a learner killed between two of
them loses the iterations since the last one (8 iterations, 32,768 steps in the measurement of
issue 54), and a resumed run used to continue as if they had never happened. The progress file
is small and replaced atomically each iteration, so a resumed run knows how far the killed one
had got and counts the difference (`faults/lost_iterations`, `faults/lost_env_steps`), and how
many value pairs the sampler had taken (`faults/value_pairs_lost` if it comes back with fewer).
"""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path

log = logging.getLogger(__name__)

FILE = "progress.json"


@dataclass(frozen=True)
class Progress:
    iteration: int
    """Policy iterations done."""
    env_steps: int
    """Environment steps trained on."""
    sampler_pairs_taken: float = 0.0
    """The sampler's `vm/pairs_taken` as the learner last knew it."""


def write(run_dir: Path, progress: Progress) -> None:
    """Replace the progress file (no fsync: it must survive a killed process, not a power cut)."""
    tmp = run_dir / f".{FILE}.tmp"
    tmp.write_text(json.dumps(asdict(progress)) + "\n")
    os.replace(tmp, run_dir / FILE)


def read(run_dir: Path) -> Progress | None:
    """The run's progress file, or None when there is none or it is unusable (logged)."""
    file = run_dir / FILE
    if not file.is_file():
        return None
    try:
        raw = json.loads(file.read_text())
        p = Progress(iteration=raw["iteration"], env_steps=raw["env_steps"],
                     sampler_pairs_taken=raw.get("sampler_pairs_taken", 0.0))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        log.error("progress file %s is unusable (%s); the steps since the checkpoint are not counted", file, exc)
        return None
    whole = all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in (p.iteration, p.env_steps))
    taken = p.sampler_pairs_taken
    if not whole or isinstance(taken, bool) or not isinstance(taken, (int, float)) or not math.isfinite(taken) or taken < 0:
        log.error("progress file %s holds %s; expected whole numbers >= 0; not used", file, asdict(p))
        return None
    return p
