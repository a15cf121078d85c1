"""`morphmimic bench env-steps --against REV`: a control step's cost in this tree against the same
step in another git revision, and whether the two compute the same trajectories.

For optimizing the environments' Python (observation, reward, termination) without changing
what they compute. The other revision is checked out into a temporary `git worktree`; each
round runs one subprocess per tree (alternating which goes first, so background load hits both
alike) that, per preset, resets on the preset's base shape, steps `--steps` control steps with
seeded random actions (restarting episodes that end) and reports milliseconds per step and a
digest of every observation, reward and end flag. Reported per preset: the median over rounds
for each tree, their ratio (other / this: above 1 means this tree is faster) and whether the
digests agree (the trajectories are bit for bit the same). Nothing listens; nothing is written
outside the temporary worktree.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from learner.evaluation import cli_args

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_PRESETS = "executor,executor-pd,quadruped,lower_biped,fish"


def time_presets(presets: list[str], steps: int, seed: int) -> dict[str, dict[str, object]]:
    """In this process: per preset, ms per control step and a SHA-256 of the trajectory."""
    from common.tasks.registry import make_env
    from learner.presets import PRESETS

    out: dict[str, dict[str, object]] = {}
    for name in presets:
        env = make_env(PRESETS[name][1].task, seed=seed)
        params = env.space.default_array
        rng = np.random.default_rng(seed)
        digest = hashlib.sha256()
        obs, _ = env.reset(seed, params)
        digest.update(np.asarray(obs).tobytes())
        elapsed = 0.0
        for _ in range(steps):
            action = (0.3 * rng.standard_normal(env.act_dim)).astype(np.float32)
            start = time.perf_counter()
            obs, reward, terminated, truncated, _ = env.step(action)
            elapsed += time.perf_counter() - start
            digest.update(np.asarray(obs).tobytes() + np.float64(reward).tobytes() + bytes([terminated, truncated]))
            if terminated or truncated:
                obs, _ = env.reset(None, params)
                digest.update(np.asarray(obs).tobytes())
        out[name] = {"step_ms": 1e3 * elapsed / steps, "digest": digest.hexdigest()}
    return out


def _run_tree(tree: Path, presets: list[str], steps: int, seed: int) -> dict[str, dict[str, object]]:
    code = ("import json, sys; from learner.bench.env_steps import time_presets; "
            f"print(json.dumps(time_presets({presets!r}, {steps}, {seed})))")
    if not (tree / "learner" / "bench" / "env_steps.py").is_file():
        # NOTE: a revision older than this benchmark: run this file's function against its modules.
        here = str(Path(__file__))
        code = (f"import json, sys; sys.path.insert(0, {str(tree)!r}); g = {{'__file__': {here!r}, '__name__': 'env_steps'}}; "
                f"exec(compile(open({here!r}).read(), {here!r}, 'exec'), g); "
                f"print(json.dumps(g['time_presets']({presets!r}, {steps}, {seed})))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=tree, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"timing in {tree} failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="morphmimic bench env-steps", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--against", required=True, help="git revision to compare with (e.g. HEAD~1, a commit id)")
    parser.add_argument("--presets", default=DEFAULT_PRESETS, help="comma-separated training presets")
    parser.add_argument("--steps", type=cli_args.positive_int, default=400, help="control steps per preset and round")
    parser.add_argument("--rounds", type=cli_args.positive_int, default=5, help="rounds, each timing both trees")
    parser.add_argument("--seed", type=cli_args.seed, default=0)
    args = parser.parse_args(argv)
    from learner.presets import PRESETS

    presets = [p.strip() for p in args.presets.split(",") if p.strip()]
    unknown = [p for p in presets if p not in PRESETS]
    if unknown:
        parser.error(f"--presets: unknown {', '.join(unknown)}; choose from {', '.join(sorted(PRESETS))}")
    rev = subprocess.run(["git", "rev-parse", "--verify", f"{args.against}^{{commit}}"], cwd=ROOT,
                         capture_output=True, text=True, check=False)
    if rev.returncode != 0:
        parser.error(f"--against {args.against!r} is not a commit of this repository")
    with tempfile.TemporaryDirectory(prefix="env-steps-") as tmp:
        other = Path(tmp) / "tree"
        subprocess.run(["git", "worktree", "add", "--detach", str(other), rev.stdout.strip()], cwd=ROOT,
                       capture_output=True, check=True)
        try:
            times: dict[str, dict[str, list[float]]] = {p: {"this": [], "other": []} for p in presets}
            digests: dict[str, dict[str, set[str]]] = {p: {"this": set(), "other": set()} for p in presets}
            for r in range(args.rounds):
                order = [("this", ROOT), ("other", other)]
                for label, tree in (order if r % 2 == 0 else order[::-1]):
                    for name, m in _run_tree(tree, presets, args.steps, args.seed).items():
                        times[name][label].append(float(m["step_ms"]))
                        digests[name][label].add(str(m["digest"]))
                print(f"round {r + 1}/{args.rounds} done", flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(other)], cwd=ROOT, capture_output=True, check=False)
    print(f"control step, this tree against {args.against} ({rev.stdout.strip()[:10]}); {args.steps} steps x {args.rounds} rounds")
    print(f"{'preset':<14} {'this ms':>8} {'other ms':>9} {'other/this':>10}  same trajectory")
    for name in presets:
        this, oth = statistics.median(times[name]["this"]), statistics.median(times[name]["other"])
        same = digests[name]["this"] == digests[name]["other"] and len(digests[name]["this"]) == 1
        print(f"{name:<14} {this:8.3f} {oth:9.3f} {oth / this:10.2f}  {'yes' if same else 'NO'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
