"""`morphmimic bench env-steps --against REV`: a control step's cost in this tree against the same
step in another git revision, and whether the two compute the same trajectories.

For optimizing the environments' Python (observation, reward, termination) without changing
what they compute. The other revision is checked out into a temporary `git worktree`; each
round runs one subprocess per tree (alternating which goes first, so background load hits both
alike) that, per preset, resets on the preset's base shape, steps `--steps` control steps with
seeded random actions (restarting episodes that end, or every `--episode-steps` steps: about 40
is an early training run's episode) and reports milliseconds per step, milliseconds per reset and
a digest of every observation, reward and end flag. Reported per preset: the median over rounds
for each tree, their ratios (other / this: above 1 means this tree is faster) and whether the
digests agree (the trajectories are bit for bit the same). Nothing listens; besides the
temporary worktree, git records it under `.git/worktrees` until it is removed (and pruned).
"""

from __future__ import annotations

import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from common.config_limits import SEED, Limit, at_least, check_limits, validated
from learner.cli_options import CommaStrs, parse_options, refuse


ROOT = Path(__file__).resolve().parents[2]
DEFAULT_PRESETS = "executor,executor-pd,quadruped,lower_biped,fish"


def time_presets(presets: list[str], steps: int, seed: int, episode_steps: int = 0) -> dict[str, dict[str, object]]:
    """In this process: per preset, ms per control step, ms per reset and a SHA-256 of the
    trajectory; `episode_steps` > 0 also restarts an episode after that many steps."""
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
        elapsed = reset_s = 0.0
        resets = length = 0
        for _ in range(steps):
            action = (0.3 * rng.standard_normal(env.act_dim)).astype(np.float32)
            start = time.perf_counter()
            obs, reward, terminated, truncated, _ = env.step(action)
            elapsed += time.perf_counter() - start
            length += 1
            digest.update(np.asarray(obs).tobytes() + np.float64(reward).tobytes() + bytes([bool(terminated), bool(truncated)]))
            if terminated or truncated or length == episode_steps:
                start = time.perf_counter()
                obs, _ = env.reset(None, params)
                reset_s += time.perf_counter() - start
                resets, length = resets + 1, 0
                digest.update(np.asarray(obs).tobytes())
        out[name] = {"step_ms": 1e3 * elapsed / steps, "reset_ms": 1e3 * reset_s / max(resets, 1), "resets": resets,
                     "digest": digest.hexdigest()}
    return out


def _run_tree(tree: Path, presets: list[str], steps: int, seed: int, episode_steps: int) -> dict[str, dict[str, object]]:
    """`time_presets` in a subprocess that imports `tree`'s modules: the tree goes first on the
    path explicitly (an editable install's import hook would otherwise serve this checkout's
    modules, e.g. under PYTHONSAFEPATH), this file's function runs against them (so revisions
    older than this benchmark can be timed), and the modules' location is checked."""
    here = str(Path(__file__))
    code = (f"import json, sys; sys.path.insert(0, {str(tree)!r}); g = {{'__file__': {here!r}, '__name__': 'env_steps'}}; "
            f"exec(compile(open({here!r}).read(), {here!r}, 'exec'), g); import common; "
            f"print(json.dumps({{'from': common.__file__, 'presets': g['time_presets']({presets!r}, {steps}, {seed}, {episode_steps})}}))")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONSAFEPATH"}
    proc = subprocess.run([sys.executable, "-c", code], cwd=tree, env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"timing in {tree} failed:\n{proc.stderr[-2000:]}")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    if not Path(out["from"]).resolve().is_relative_to(tree.resolve()):
        raise RuntimeError(f"the timing meant for {tree} imported {out['from']}: the comparison would not compare two trees")
    return out["presets"]


def _git(*args: str) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=False)
    except FileNotFoundError as exc:
        raise SystemExit("morphmimic bench env-steps: git is not installed; it checks out the other revision") from exc


PROG = "morphmimic bench env-steps"


@validated
@dataclass
class EnvStepsBenchOptions:
    against: str
    """Git revision to compare with (e.g. HEAD~1, a commit id)."""
    presets: CommaStrs = tuple(DEFAULT_PRESETS.split(","))
    """Comma-separated training presets."""
    steps: int = 400
    """Control steps per preset and round."""
    rounds: int = 5
    """Rounds, each timing both trees."""
    seed: int = 0
    """Seed of the actions."""
    episode_steps: int | None = None
    """Also restart an episode after this many steps (default: only when it ends)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"steps": at_least(1), "rounds": at_least(1), "seed": SEED, "episode_steps": at_least(1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(EnvStepsBenchOptions, argv, prog=PROG, description=__doc__)
    from learner.presets import PRESETS

    presets = list(args.presets)
    unknown = [p for p in presets if p not in PRESETS]
    if unknown:
        refuse(PROG, f"--presets: unknown {', '.join(unknown)}; choose from {', '.join(sorted(PRESETS))}")
    rev = _git("rev-parse", "--verify", f"{args.against}^{{commit}}")
    if rev.returncode != 0:
        shallow = _git("rev-parse", "--is-shallow-repository").stdout.strip() == "true"
        refuse(PROG, f"--against {args.against!r} is not a commit of this repository ({rev.stderr.strip() or 'git failed'})"
                     + ("; this clone is shallow: `git fetch --deepen N` or `--unshallow` brings older commits" if shallow else ""))
    with tempfile.TemporaryDirectory(prefix="env-steps-") as tmp:
        other = Path(tmp) / "tree"
        added = _git("worktree", "add", "--detach", str(other), rev.stdout.strip())
        if added.returncode != 0:
            raise SystemExit(f"morphmimic bench env-steps: git worktree add failed: {added.stderr.strip()}")
        try:
            times: dict[str, dict[str, list[float]]] = {p: {"this": [], "other": []} for p in presets}
            reset_ms: dict[str, dict[str, list[float]]] = {p: {"this": [], "other": []} for p in presets}
            resets: dict[str, int] = {}
            digests: dict[str, dict[str, set[str]]] = {p: {"this": set(), "other": set()} for p in presets}
            for r in range(args.rounds):
                order = [("this", ROOT), ("other", other)]
                for label, tree in (order if r % 2 == 0 else order[::-1]):
                    for name, m in _run_tree(tree, presets, args.steps, args.seed, args.episode_steps or 0).items():
                        times[name][label].append(float(m["step_ms"]))
                        reset_ms[name][label].append(float(m["reset_ms"]))
                        resets[name] = int(m["resets"])
                        digests[name][label].add(str(m["digest"]))
                print(f"round {r + 1}/{args.rounds} done", flush=True)
        finally:
            _git("worktree", "remove", "--force", str(other))
            _git("worktree", "prune")
    print(f"control step and reset, this tree against {args.against} ({rev.stdout.strip()[:10]}); {args.steps} steps x "
          f"{args.rounds} rounds" + (f", episodes of at most {args.episode_steps} steps" if args.episode_steps else ""))
    print(f"{'preset':<14} {'this ms':>8} {'other ms':>9} {'other/this':>10} {'resets':>7} {'reset ms':>9} {'other ms':>9} "
          f"{'other/this':>10}  same trajectory")
    for name in presets:
        this, oth = statistics.median(times[name]["this"]), statistics.median(times[name]["other"])
        r_this, r_oth = statistics.median(reset_ms[name]["this"]), statistics.median(reset_ms[name]["other"])
        r_ratio = f"{r_oth / r_this:10.2f}" if resets[name] and r_this > 0 else f"{'-':>10}"
        same = digests[name]["this"] == digests[name]["other"] and len(digests[name]["this"]) == 1
        print(f"{name:<14} {this:8.3f} {oth:9.3f} {oth / this:10.2f} {resets[name]:7d} {r_this:9.3f} {r_oth:9.3f} {r_ratio}"
              f"  {'yes' if same else 'NO'}")
    return 0
