"""One learner process of `morphmimic bench soak`: trains on the soak's cluster, injects the
in-process faults (`soak_faults.py`), and after every iteration writes a status file the soak
reads: progress, the run's counters, the faults and their outcomes. A learner of its own
process, so that the soak can SIGKILL it and resume it like any crashed learner.

    python -m learner.bench.soak_learner SPEC.json

SPEC.json (written by soak.py): preset, runs_dir, name, ray_address, resume ("auto"/"never"),
total_env_steps, seed, fault_every_s (0: no faults), kinds, status (path), control (a
directory: the soak creates `quiet` there to end the injections, `hold` to pause them, `stop` to
stop the learner as Ctrl-C would; checked after every iteration). At the stop, the status also holds the loss
accounting of the whole run so far (soak_report.py).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from learner.bench.soak_faults import InProcessFaults, losses_finite

SPEC_FIELDS = {"preset": str, "runs_dir": str, "name": str, "ray_address": str, "resume": str, "total_env_steps": int,
               "seed": int, "fault_every_s": float, "kinds": list, "status": str, "control": str}


def read_spec(path: str) -> dict:
    """The spec, every field present and of its type; ValueError naming the first that is not."""
    spec = json.loads(Path(path).read_text())
    for name, kind in SPEC_FIELDS.items():
        value = spec.get(name)
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = spec[name] = float(value)
        if not isinstance(value, kind) or (kind is float and not math.isfinite(value)):
            raise ValueError(f"{path}: {name} must be a {kind.__name__}, got {value!r}")
    if spec["resume"] not in ("auto", "never"):
        raise ValueError(f"{path}: resume must be auto or never, got {spec['resume']!r}")
    return spec


def ledger(run_dir: Path) -> dict[int, int]:
    """Unrolls each actor numbered over the whole run (its durable sequence ledger + 1)."""
    out = {}
    for p in (run_dir / "ledger").glob("actor-*.seq"):
        raw = p.read_text().strip("\0 \n")
        out[int(p.stem.split("-")[1])] = int(raw) + 1 if raw.isdigit() else 0
    return out


def _write(path: Path, status: dict) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(status, default=float))
    os.replace(tmp, path)


def _status(run, metrics: dict, faults, first_iteration: int, final: bool) -> dict:
    t = run.transport
    keep = ("faults/", "lost/", "wire/", "sampler/requests/", "stats/divergences", "charts/", "losses/")
    out = {
        "pid": os.getpid(), "time": time.time(), "final": final, "first_iteration": first_iteration,
        "iteration": run.learner.iteration, "env_steps": run.learner.env_steps,
        "last_saved": run.last_saved, "episodes": run.learner.episodes,
        "losses_finite": losses_finite(metrics),
        "return": metrics.get("charts/episode_return", float("nan")),
        "metrics": {k: float(v) for k, v in metrics.items() if k.startswith(keep)},
        "counters": {k: int(v) for k, v in t.counters.items()},
        "learner_counters": {k: int(v) for k, v in run.learner.counters.items()},
        "snapshot_replies_dropped": dict(t.snapshots.dropped),
        "faults": [dataclasses.asdict(f) for f in faults.faults] if faults else [],
        "not_injected": dict(faults.not_injected) if faults else {},
        "why_not": dict(faults.why_not) if faults else {},
    }
    if final:
        out["ledger"] = {str(k): v for k, v in ledger(run.run_dir).items()}
        out["last_seq"] = {str(k): v for k, v in t.last_seq.items()}
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m learner.bench.soak_learner SPEC.json", file=sys.stderr)
        return 2
    try:
        spec = read_spec(argv[0])
    except (OSError, ValueError) as exc:
        print(f"soak learner: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2

    from learner.presets import PRESETS  # lazy: start-up time of a bad spec's error
    from learner.train import train  # lazy: start-up time of a bad spec's error (torch, tensorboard)

    base = PRESETS[spec["preset"]][1]
    cfg = dataclasses.replace(
        base, name=spec["name"], runs_dir=spec["runs_dir"], mode="cluster", ray_address=spec["ray_address"],
        resume=spec["resume"], total_env_steps=spec["total_env_steps"], checkpoint_every=3, stall_timeout_s=5.0,
        quiet=True, seed=spec["seed"], vm_plot_every=0,
        actors=dataclasses.replace(base.actors, num_actors=2, sampler_timeout_s=0.5, sampler_retries=1),
    )
    faults = None
    if spec["fault_every_s"] > 0 and spec["kinds"]:
        faults = InProcessFaults(np.random.default_rng(spec["seed"]), spec["fault_every_s"], kinds=tuple(spec["kinds"]))
    status_path, control = Path(spec["status"]), Path(spec["control"])
    seen: dict = {}

    def hook(run, metrics: dict) -> None:
        seen.setdefault("first", run.learner.iteration)
        seen["run"], seen["metrics"] = run, metrics
        if faults is not None:
            faults.quiet = (control / "quiet").exists() or (control / "hold").exists()
            faults(run, metrics)
        _write(status_path, _status(run, metrics, faults, seen["first"], final=False))
        if (control / "stop").exists():
            run.stop.request()

    try:
        train(cfg, on_iteration=hook)
    finally:
        if faults is not None:
            faults.close()
    if "run" in seen:
        _write(status_path, _status(seen["run"], seen["metrics"], faults, seen["first"], final=True))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
