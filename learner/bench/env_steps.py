"""`morphmimic bench env-steps --against REV`: a control step's cost in this tree against the same
step in another git revision, and whether the two compute the same trajectories.

For optimizing the environments' Python (observation, reward, termination) without changing
what they compute. The other revision is checked out into a temporary `git worktree`; each
round runs one subprocess per tree (alternating which goes first, so background load hits both
alike) that, per preset, resets on the preset's base shape, steps `--steps` control steps with
seeded random actions (restarting episodes that end, or every `--episode-steps` steps: about 40
is an early training run's episode) and reports milliseconds per step, milliseconds per reset and
a digest of every observation, reward and end flag; then, in the same process, a pure physics
loop of the same model (`mj_step` x substeps, on one MjData and on `--envs` of them) and
`--envs` environments stepped as one batch (`make_batch_env`; in a tree without it, single
environments one after another) with a digest of all their trajectories. Reported per preset:
the median over rounds for each tree, their ratios (other / this: above 1 means this tree is
faster) and whether the digests agree (the trajectories are bit for bit the same); and per tree
the single and the batched control step per environment as ratios of the physics loop. Nothing
listens; besides the temporary worktree, git records it under `.git/worktrees` until it is
removed (and pruned).
"""

from __future__ import annotations

import inspect
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


def time_presets(presets: list[str], steps: int, seed: int, episode_steps: int = 0, envs: int = 0) -> dict[str, dict[str, object]]:
    """In this process: per preset, ms per control step, ms per reset and a SHA-256 of the
    trajectory of one environment; `episode_steps` > 0 also restarts an episode after that many
    steps. Also, in the same process: `physics_ms`, a pure physics loop of the same model
    (`mj_step` x substeps on one MjData, restarted like the episodes); and with `envs` > 0, the
    same for a batch of that many environments (`time_batch`)."""
    import hashlib  # lazy: this function's source runs in another tree's subprocess (--against), so it imports what it uses
    import time  # lazy: this function's source runs in another tree's subprocess (--against), so it imports what it uses

    import mujoco  # lazy: this function's source runs in another tree's subprocess (--against), so it imports what it uses
    import numpy as np  # lazy: this function's source runs in another tree's subprocess (--against), so it imports what it uses

    from common.tasks.registry import make_env  # lazy: this function's source runs in another tree's subprocess (--against), so it imports what it uses
    from learner.presets import PRESETS  # lazy: this function's source runs in another tree's subprocess (--against), so it imports what it uses

    out: dict[str, dict[str, object]] = {}
    for name in presets:
        task = PRESETS[name][1].task
        env = make_env(task, seed=seed)
        params = env.space.default_array
        rng = np.random.default_rng(seed)
        digest = hashlib.sha256()
        obs, _ = env.reset(seed, params)
        start_qpos = env.data.qpos.copy()
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
        datas = [mujoco.MjData(env.model) for _ in range(max(envs, 1))]
        elapsed = 0.0
        for k in range(steps):
            if k % (episode_steps or 40) == 0:
                for d in datas:
                    mujoco.mj_resetData(env.model, d)
                    d.qpos[:] = start_qpos
            start = time.perf_counter()
            for d in datas:
                mujoco.mj_step(env.model, d, nstep=task.substeps)
            elapsed += time.perf_counter() - start
        out[name]["physics_ms"] = 1e3 * elapsed / (steps * len(datas))
        if envs:
            out[name].update(time_batch(name, steps, seed, episode_steps, envs))
    return out


def time_batch(preset: str, steps: int, seed: int, episode_steps: int, envs: int) -> dict[str, object]:
    """In this process: `envs` environments of `preset` (seeds seed + i) stepped together
    `steps` times with seeded random actions, restarted like `time_presets`'s: through the
    task's `make_batch_env` where the tree has it, else as single environments one after
    another. Returns ms per environment step (`batch_step_ms`) and a SHA-256 of all
    environments' trajectories (`batch_digest`), the same whichever way they were stepped when
    each environment behaves as alone."""
    import hashlib  # lazy: this function's source runs in another tree's subprocess (--against), so it imports what it uses
    import time  # lazy: this function's source runs in another tree's subprocess (--against), so it imports what it uses

    import numpy as np  # lazy: this function's source runs in another tree's subprocess (--against), so it imports what it uses

    from common.tasks import registry  # lazy: this function's source runs in another tree's subprocess (--against), so it imports what it uses
    from learner.presets import PRESETS  # lazy: this function's source runs in another tree's subprocess (--against), so it imports what it uses

    task = PRESETS[preset][1].task
    seeds = [seed + i for i in range(envs)]
    if hasattr(registry, "make_batch_env"):
        batch = registry.make_batch_env(task, seeds)
        act_dim, space = batch.act_dim, batch.space

        def reset(i: int, s: int | None) -> np.ndarray:
            return batch.reset_one(i, s, space.default_array)

        step = batch.step
    else:
        singles = [registry.make_env(task, s) for s in seeds]
        act_dim, space = singles[0].act_dim, singles[0].space

        def reset(i: int, s: int | None) -> np.ndarray:
            return singles[i].reset(s, space.default_array)[0]

        def step(actions: np.ndarray):
            rows = [env.step(a) for env, a in zip(singles, actions)]
            return (np.stack([r[0] for r in rows]), np.array([r[1] for r in rows]), np.array([r[2] for r in rows]),
                    np.array([r[3] for r in rows]), [r[4] for r in rows])

    rng = np.random.default_rng(seed)
    digest = hashlib.sha256()
    for i, s in enumerate(seeds):
        digest.update(np.asarray(reset(i, s)).tobytes())
    lengths = np.zeros(envs, np.int64)
    elapsed = 0.0
    for _ in range(steps):
        actions = (0.3 * rng.standard_normal((envs, act_dim))).astype(np.float32)
        start = time.perf_counter()
        obs, rewards, terminated, truncated, _ = step(actions)
        elapsed += time.perf_counter() - start
        lengths += 1
        for i in range(envs):
            digest.update(np.asarray(obs[i]).tobytes() + np.float64(rewards[i]).tobytes()
                          + bytes([bool(terminated[i]), bool(truncated[i])]))
            if terminated[i] or truncated[i] or lengths[i] == episode_steps:
                digest.update(np.asarray(reset(i, None)).tobytes())
                lengths[i] = 0
    return {"batch_step_ms": 1e3 * elapsed / (steps * envs), "batch_digest": digest.hexdigest()}


def _run_tree(tree: Path, presets: list[str], steps: int, seed: int, episode_steps: int, envs: int) -> dict[str, dict[str, object]]:
    """`time_presets` in a subprocess that imports `tree`'s modules: the tree goes first on the
    path explicitly (an editable install's import hook would otherwise serve this checkout's
    modules, e.g. under PYTHONSAFEPATH), this file's function runs against them (so revisions
    older than this benchmark can be timed), and the modules' location is checked."""
    # NOTE: only the timing functions are shipped (their imports are inside them), so a revision
    # older than this benchmark's own imports can be timed.
    source = "\n\n".join(inspect.getsource(f) for f in (time_presets, time_batch))
    code = (f"import json, sys\nsys.path.insert(0, {str(tree)!r})\n{source}\nimport common\n"
            f"print(json.dumps({{'from': common.__file__, 'presets': time_presets({presets!r}, {steps}, {seed}, "
            f"{episode_steps}, {envs})}}))")
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
    envs: int = 8
    """Environments stepped as one batch (`make_batch_env`; one after another in a tree without it)."""

    LIMITS: ClassVar[dict[str, Limit]] = {"steps": at_least(1), "rounds": at_least(1), "seed": SEED, "episode_steps": at_least(1), "envs": at_least(1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(EnvStepsBenchOptions, argv, prog=PROG, description=__doc__)
    from learner.presets import PRESETS  # lazy: start-up time of --help (the presets load torch)

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
            physics: dict[str, dict[str, list[float]]] = {p: {"this": [], "other": []} for p in presets}
            batch: dict[str, dict[str, list[float]]] = {p: {"this": [], "other": []} for p in presets}
            resets: dict[str, int] = {}
            digests: dict[str, dict[str, set[str]]] = {p: {"this": set(), "other": set()} for p in presets}
            batch_digests: dict[str, dict[str, set[str]]] = {p: {"this": set(), "other": set()} for p in presets}
            for r in range(args.rounds):
                order = [("this", ROOT), ("other", other)]
                for label, tree in (order if r % 2 == 0 else order[::-1]):
                    for name, m in _run_tree(tree, presets, args.steps, args.seed, args.episode_steps or 0, args.envs).items():
                        times[name][label].append(float(m["step_ms"]))
                        reset_ms[name][label].append(float(m["reset_ms"]))
                        physics[name][label].append(float(m["physics_ms"]))
                        batch[name][label].append(float(m["batch_step_ms"]))
                        resets[name] = int(m["resets"])
                        digests[name][label].add(str(m["digest"]))
                        batch_digests[name][label].add(str(m["batch_digest"]))
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
    print(f"\nagainst a pure physics loop of the same model in the same process (mj_step x substeps; for the batch, "
          f"over {args.envs} MjData), ms per environment step, medians over rounds")
    print(f"{'preset':<14} {'tree':<6} {'physics':>8} {'single':>8} {'single/phys':>11} {'batch':>8} {'batch/phys':>10} "
          f"{'single/batch':>12}  same batched trajectory")
    for name in presets:
        same = batch_digests[name]["this"] == batch_digests[name]["other"] and len(batch_digests[name]["this"]) == 1
        for label in ("this", "other"):
            ph, si, ba = (statistics.median(x[name][label]) for x in (physics, times, batch))
            print(f"{name:<14} {label:<6} {ph:8.3f} {si:8.3f} {si / ph:11.2f} {ba:8.3f} {ba / ph:10.2f} {si / ba:12.2f}"
                  + (f"  {'yes' if same else 'NO'}" if label == "this" else ""))
    return 0
