"""The sampler service's own state file: `<state_dir>/sampler-state.npz`, written atomically.

Before it, a killed sampler came back from the learner's last checkpoint: every value pair since
(16 iterations' worth at the default `checkpoint_every`) was gone, and actors drew from an empty
buffer until the learner noticed and sent the checkpoint's state (15 s). The service now saves
on its own schedule and on stop, and a restarted service loads the file before it serves its
first draw.

Format: one `.npz` with the state's arrays under their names and the meta as JSON text under
`META_KEY`; `numpy.load(allow_pickle=False)` reads it, so the file cannot run code. Written to
a temporary file, fsynced and renamed over the old one: a kill mid-write leaves the previous.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

FILE = "sampler-state.npz"
META_KEY = "__meta__"


def path_in(state_dir: str | Path) -> Path:
    return Path(state_dir) / FILE


def save(state_dir: str | Path, state: dict[str, Any]) -> Path:
    """Write `state` (`ShapeSampler.state_dict()`) into `state_dir`; returns the file."""
    folder = Path(state_dir)
    folder.mkdir(parents=True, exist_ok=True)
    final = path_in(folder)
    tmp = folder / f".{FILE}.{os.getpid()}.tmp"
    arrays = {k: np.asarray(v) for k, v in state["arrays"].items()}
    if META_KEY in arrays:
        raise ValueError(f"sampler state array named {META_KEY!r}: the name is reserved for the meta")
    with open(tmp, "wb") as f:
        np.savez(f, **{META_KEY: np.array(json.dumps(state["meta"]))}, **arrays)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, final)
    return final


def load(state_dir: str | Path) -> dict[str, Any] | None:
    """The state saved in `state_dir`, or None when there is none. A file that cannot be read is
    logged and treated as none (the learner's checkpoint copy is the fallback)."""
    file = path_in(state_dir)
    if not file.is_file():
        return None
    try:
        with np.load(file, allow_pickle=False) as data:
            meta = json.loads(str(data[META_KEY]))
            arrays = {k: np.array(data[k]) for k in data.files if k != META_KEY}
    except Exception as exc:  # noqa: BLE001 - truncated, foreign or hand-edited: all "no usable state"
        log.error("sampler state file %s cannot be read (%s: %s); starting without it", file, type(exc).__name__, exc)
        return None
    if not isinstance(meta, dict):
        log.error("sampler state file %s has meta of type %s; starting without it", file, type(meta).__name__)
        return None
    return {"meta": meta, "arrays": arrays}
