"""Each executor clip's length, without loading a clip: what the sampler needs to draw start
times (`sampler/time_bins.py`) and to check the failure times the actors report.

The lengths come from the manifest (`frames`, `fps`): loading the full library's 480 clips to
read their lengths would cost the learner over a second at every start. A loaded clip was at
most 0.2 ms shorter than its manifest length (measured on the core clips and every tenth of the
full library: an import may resample), which the sampler's end margin (`time_bins.END_MARGIN_S`)
absorbs. A mirror image (`<id>~mirror`)
lasts as long as its source.
"""

from __future__ import annotations

from common.motion.manifest import load_manifest
from common.motion.mirror import source_id
from common.tasks.base import TaskConfig
from common.tasks.executor.env import executor_clips


def executor_clip_durations(cfg: TaskConfig) -> dict[str, float]:
    """{clip id: duration in s} of every clip the task draws (`executor_clips`)."""
    manifest = load_manifest()
    return {cid: float(manifest.by_id(source_id(cid)).duration_s) for cid, _ in executor_clips(cfg)}
