"""Does a run's marginal value function point at the bodies its evaluation finds hardest?

For the record 2026-12-08-executor-shape-adaptive-k1.md. Usage, from the repository root:

    python docs/experiments/2026-12-08-vm-against-success.py <run>/sampler/sampler-state.npz runs/eval/<dir> [...]

For each evaluation episode whose clip's class the sampler knows, Vm(shape, class) is expressed relative
to that class's average over the box, in units of its spread over the box ((Vm - Vbar_c) / probe_std_c).
It prints the correlation with success, the success of the episodes in that value's lowest decile against
the rest, and the mean relative value on the success map's worst-decile bodies."""

from __future__ import annotations

import json
import pathlib
import shutil
import sys
import tempfile

import numpy as np

from sampler import state_file
from sampler.clip_metrics import clip_class
from sampler.marginal_value import MarginalValue


def main(state_path: str, eval_dirs: list[str]) -> None:
    if not pathlib.Path(state_path).is_file():
        sys.exit(f"{state_path}: no such file; give a run's sampler/sampler-state.npz")
    for out in eval_dirs:
        if not (pathlib.Path(out) / "results.json").is_file():
            sys.exit(f"{out}: no results.json; give a directory written by `morphmimic evaluate --shapes N`")
    tmp = pathlib.Path(tempfile.mkdtemp())
    shutil.copy(state_path, tmp / "sampler-state.npz")
    state = state_file.load(tmp)
    meta = (state or {}).get("meta", {}).get("vm", {})
    if not meta.get("classes"):
        sys.exit(f"{state_path}: not a sampler state with Vm over (shape, class); "
                 "give one from a run with --sampler.shape-by-class (the executor-shape preset)")
    arrays = {k.removeprefix("vm/"): v for k, v in state["arrays"].items() if k.startswith("vm/")}
    vm = MarginalValue(np.array(meta["low"]), np.array(meta["high"]), hidden=tuple(meta["hidden"]), classes=meta["classes"])
    vm.load_state(meta, arrays)
    index = {c: i for i, c in enumerate(meta["classes"])}
    for out in eval_dirs:
        results = json.loads((pathlib.Path(out) / "results.json").read_text())
        if "shapes" not in results.get("summary", {}):
            sys.exit(f"{out}: an evaluation without --shapes; this compares Vm with success over body shapes")
        eps = [e for e in results["episodes"] if clip_class(e["label"]) in index]
        shapes = np.array([e["shape"] for e in eps])
        success = np.array([e["success"] for e in eps], float)
        classes = np.array([index[clip_class(e["label"])] for e in eps])
        value = np.array([vm(shapes[i:i + 1], int(classes[i]))[0] for i in range(len(eps))])
        z = (value - np.array(meta["vbar_c"])[classes]) / np.maximum(np.array(meta["probe_std_c"])[classes], 1e-6)
        low = z <= np.quantile(z, 0.1)
        worst = set(results["summary"]["shapes"]["worst_decile_shapes"]["overall"]["shapes"])
        on_worst = np.array([e["shape_index"] in worst for e in eps])
        print(f"{out}: {len(eps)} of {len(results['episodes'])} episodes in known classes; "
              f"correlation of relative Vm with success {np.corrcoef(z, success)[0, 1]:.3f}; "
              f"success in Vm's lowest decile {100 * success[low].mean():.1f}% against {100 * success[~low].mean():.1f}%; "
              f"relative Vm on the map's worst-decile bodies {z[on_worst].mean():+.2f} (others {z[~on_worst].mean():+.2f})")


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2:])
