"""Per-clip evaluation of a UniCon motion executor checkpoint (METHOD.md B "Evaluation"): which
clips, which start frames, one deterministic episode per (clip, start), and the aggregates.
No files and no CLI here (`executor_report.py` writes them; `robustness.py` and
`executor_ablation.py` reuse the episodes).

Protocol. The task is built as for evaluation (`eval_task`): the scheduler stops at the clip's
end (the episode is truncated there), the character starts exactly on the tracked frame (no
reactive initialization and no catch-up grace), the policy acts with its mean action.
Each clip is started at `start_times` (evenly over its first 80%, no randomness).

One run per episode, with the environment's termination switched off: termination changes
nothing in the dynamics, it only cuts the episode, so the trajectory with termination off is
the one every termination rule would have produced up to its own end. The run records the
first step at which each criterion fails, and every metric is read off that one trajectory:

- success (UniCon): tracked to the clip's end with no reward term below alpha (the per-term
  rule, for every checkpoint alike, whatever rule it trained with) and no simulator divergence;
- pose success: the same with only the four pose terms watched (joint velocity left out, as
  the executor presets train: `ExecutorConfig.terminate_on`);
- PHC success (Luo et al. 2023): the mean global body-position error (`body_error_m`) never
  above 0.5 m before the clip's end; measured on the trajectory not cut by UniCon's rule, as
  PHC's evaluation terminates on its own criterion only;
- the episode "as the checkpoint runs it": cut at the first step its own termination rule
  (`ExecutorConfig.termination`: per_term, sum or none) ends it. Its return, mean reward per
  step, MPJPE (mean root-relative body-position error, `joint_error_m`, in mm) and global mean
  body-position error (mm) are over that episode's steps.

Running two environments (termination on, then off) would give the same numbers at about
twice the cost.
"""

from __future__ import annotations

import dataclasses
import json
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np
import torch

from common.motion import bandai
from common.motion.errors import ClipError
from common.motion.library import import_source
from common.motion.mirror import MIRROR_SUFFIX
from common.tasks.base import TaskConfig
from common.tasks.executor import rewards as rw
from common.params import ParamSpace
from common.tasks.executor.env import CHARACTER, ExecutorEnv, humanoid_clips, labelled_clips
from common.tasks.registry import make_env
from learner.config import RunConfig, _from_dict
from learner.evaluation import harness
from learner.evaluation.shape.episodes import extremeness
from learner import checkpoint

PHC_THRESHOLD_M = 0.5
"""PHC's failure criterion: the mean body-position error above this (m) fails the clip."""
START_SPAN = 0.8
"""Start frames are spread over this fraction of a clip's duration (from its first frame)."""
EVAL_EPISODE_S = 3600.0
"""Time limit of an evaluation episode: far beyond any clip (the scheduler stops at its end)."""
CLIP_SUFFIXES = (".npz", ".bvh", ".txt", ".json")
SPLITS = ("train", "test", "unused", "imported")
"""Split tags: train = a clip the checkpoint trained on; test = UniCon's held-out split of the
checkpoint's config (not trained on); unused = any other humanoid clip the checkpoint did not
train on (a checkpoint trained on an explicit clip list); imported = a file given to --clips."""


class ClipSelectionError(ValueError):
    """A --clips value that names no clip (unknown id, missing file, folder without clips)."""


@dataclass(frozen=True)
class EvalClip:
    """One clip to evaluate: its id in the environment, class label, split tag (`SPLITS`), and
    for a file the imported clip (registered with `ExecutorEnv.register_clip`)."""

    clip_id: str
    label: str
    split: str
    clip: Any = None
    source: str = ""


@dataclass(frozen=True)
class Perturbation:
    """What a robustness row changes (UniCon Table 2); the default changes nothing.

    speed: playback speed of the targets (`ExecutorConfig.speed`); mass: every body of the
    character `mass` times heavier (`ExecutorEnv.scale_mass`); projectile_every: control steps
    between two throws of the projectile (0: none), thrown at steps 0, N, 2N, ... of the episode
    by `ExecutorEnv.throw_projectile(projectile_speed_mps, projectile_distance_m, rng)`, with an
    rng seeded per (clip, start) so every row and checkpoint sees the same throws; shapes: every
    (clip, start) on this many random body shapes (`eval_shapes(cfg, shapes, shape_seed)`, the body
    varying whether or not the checkpoint trained so: `shape_task`)."""

    speed: float = 1.0
    mass: float = 1.0
    projectile_every: int = 0
    projectile_speed_mps: float = 10.0
    projectile_distance_m: float = 2.0
    shapes: int = 0
    shape_seed: int = 2019

    @property
    def is_identity(self) -> bool:
        return self.speed == 1.0 and self.mass == 1.0 and self.projectile_every == 0 and self.shapes == 0


# ---- which clips, which starts ----


def start_times(duration_s: float, n: int, span: float = START_SPAN) -> list[float]:
    """`n` start times (s) evenly spaced from 0 to `span` x the clip's duration (both ends
    included; one start: 0). Deterministic: every checkpoint starts at the same frames."""
    if n < 1:
        raise ValueError(f"starts = {n} must be >= 1")
    if n == 1:
        return [0.0]
    return [float(x) for x in np.linspace(0.0, span * duration_s, n)]


def _with_executor(cfg: TaskConfig, **changes) -> TaskConfig:
    return dataclasses.replace(cfg, executor=dataclasses.replace(cfg.executor, **changes))


def split_tags(cfg: TaskConfig) -> dict[str, str]:
    """{clip_id: "train" | "test" | "unused"} for every clip of the checkpoint's library and its mirror image (see
    `SPLITS`), from the checkpoint's task config: its clip list or split (and split seed), and
    whether it trained on mirror images (without, a train clip's mirror is "unused")."""
    trained = {c for c, _ in labelled_clips(cfg)}
    held_out = {c for c, _ in labelled_clips(_with_executor(cfg, clips=(), split="test"))}
    return {c: "train" if c in trained else "test" if c in held_out else "unused" for c, _ in humanoid_clips(mirror=True, library=cfg.executor.library)}


def default_clips(cfg: TaskConfig, splits: Iterable[str] = ("train", "test", "unused")) -> list[EvalClip]:
    """Every humanoid clip whose split tag is in `splits`, in manifest order; mirror images only
    when the checkpoint trained on them (`ExecutorConfig.mirror`; name them in --clips otherwise)."""
    tags, keep = split_tags(cfg), set(splits)
    return [EvalClip(c, label, tags[c]) for c, label in humanoid_clips(mirror=cfg.executor.mirror, library=cfg.executor.library)
            if tags[c] in keep]


def classify_clip_value(text: str) -> tuple[str, str]:
    """("id" | "file" | "folder", text) for one --clips value, or ClipSelectionError naming it:
    an unknown id, a missing file, a folder holding no `.npz` clips."""
    ids = [c for c, _ in humanoid_clips(mirror=True, library="full")]
    if text in ids:
        return "id", text
    path = Path(text)
    if path.is_dir():
        if not sorted(path.glob("*.npz")):
            raise ClipSelectionError(f"folder {text!r} holds no .npz clips (import files into it with "
                                     "`morphmimic motion import`, or name clip ids or files)")
        return "folder", text
    if path.is_file():
        if path.suffix.lower() not in CLIP_SUFFIXES:
            raise ClipSelectionError(f"file {text!r} is not a clip file ({', '.join(CLIP_SUFFIXES)})")
        return "file", text
    if path.suffix.lower() in CLIP_SUFFIXES:
        raise ClipSelectionError(f"file {text!r} does not exist")
    raise ClipSelectionError(f"{text!r} is no humanoid clip id, clip file or folder of .npz clips; "
                             f"ids: {', '.join(c for c, _ in humanoid_clips())} (each also as <id>{MIRROR_SUFFIX}, "
                             "its mirror image)")


def import_clip_file(path: Path):
    """A clip file imported onto the humanoid (`.bvh` through cross-skeleton retargeting);
    ClipError when it cannot be, or when it is bound to another character."""

    clip = import_source(path, character=CHARACTER) if path.suffix.lower() == ".bvh" else import_source(path)
    if clip.character and clip.character != CHARACTER:
        raise ClipError(f"clip is for the {clip.character!r} character, not {CHARACTER!r}; import it onto the humanoid "
                        "first (morphmimic motion import ... --character humanoid)", path=path)
    return clip


def resolve_clips(values: Iterable[str], cfg: TaskConfig) -> list[EvalClip]:
    """The clips named by --clips values (ids, files, folders of `.npz`), in the order given,
    without duplicates. Ids keep their split tag; files are tagged "imported" and get the id
    `imported/<file stem>`. Raises ClipSelectionError (naming the value) or ClipError."""
    tags, labels = split_tags(cfg), dict(humanoid_clips(mirror=True, library="full"))
    out: list[EvalClip] = []
    seen: set[str] = set()
    for value in values:
        kind, text = classify_clip_value(value)
        if kind == "id":
            if text not in seen:
                out.append(EvalClip(text, labels[text], tags.get(text, "unused")))  # a clip of another library: never trained on
                seen.add(text)
            continue
        files = sorted(Path(text).glob("*.npz")) if kind == "folder" else [Path(text)]
        for f in files:
            if str(f.resolve()) in seen:
                continue
            seen.add(str(f.resolve()))
            clip = import_clip_file(f)
            cid, n = f"imported/{f.stem}", 2
            while cid in seen:
                cid, n = f"imported/{f.stem}-{n}", n + 1
            seen.add(cid)
            out.append(EvalClip(cid, clip.label or "root", "imported", clip, str(f)))
    return out


# ---- episodes ----


def eval_task(cfg: TaskConfig, perturbation: Perturbation = Perturbation(), shapes: bool = False) -> TaskConfig:
    """The checkpoint's task as evaluated (module docstring): every humanoid clip and its mirror
    image trackable, a stopping scheduler, no reactive initialization, termination off (read off
    the trajectory instead), a time limit no clip reaches; the row's playback speed and projectile
    body. `shapes`: the body varies (`shape_task`), whether or not the checkpoint trained so."""
    ex = dataclasses.replace(cfg.executor, clips=(), split="all", mirror=True, at_clip_end="stop", reactive_init=False,
                             on_frame_share=0.0, catch_up_steps=0, termination="none", speed=perturbation.speed,
                             projectile=perturbation.projectile_every > 0)
    out = dataclasses.replace(cfg, episode_s=EVAL_EPISODE_S, executor=ex)
    return shape_task(out) if shapes else out


# ---- body shapes (issue 55 item 3) ----

SHAPE_SEED = 2019
"""Default seed of the evaluation's shape draws (the shape controllers' evaluation's too)."""


def shape_task(cfg: TaskConfig) -> TaskConfig:
    """`cfg` with the body varying over the whole box of its parameterization
    (`--task.body.vary-shape`, box scale 1): each reset builds the body of the episode's shape
    and retargets the clip onto it. On a checkpoint trained on the base body only this is the
    zero-shot test (the baseline a shape executor is measured against): the same bodies, the
    same retargeted clips, the same size-normalized position terms (the base body's factor is 1)."""
    return dataclasses.replace(cfg, body=dataclasses.replace(cfg.body, vary_shape=True, shape_box_scale=1.0))


def shape_space(cfg: TaskConfig) -> ParamSpace:
    """The shape parameters' box the evaluation draws from (`shape_task`'s)."""
    return ExecutorEnv.param_space(shape_task(cfg))


def eval_shapes(cfg: TaskConfig, n: int, seed: int = SHAPE_SEED) -> np.ndarray:
    """`[n, P]` shapes drawn uniformly over `shape_space(cfg)` by a generator seeded with `seed`
    (`ParamSpace.uniform`): every checkpoint of one parameterization sees the same bodies."""
    if n < 1:
        raise ValueError(f"shapes = {n} must be >= 1")
    return shape_space(cfg).uniform(np.random.default_rng(seed), n)


CLIP_ROTATION_STREAM = 1
"""`shape_clip_assignment` shuffles with numpy `default_rng([seed, CLIP_ROTATION_STREAM])`: a stream
of its own, so which clips a body runs does not correlate with the body `eval_shapes(cfg, n, seed)`
draws from `default_rng(seed)`."""


def shape_clip_assignment(clip_ids: Sequence[str], shapes: int, per_shape: int,
                          seed: int = SHAPE_SEED) -> list[tuple[str, ...]]:
    """The clips each of `shapes` bodies (N) runs under `--clips-per-shape per_shape` (K), shape
    index -> clip ids: the ids sorted (the order --clips names them in does not matter), shuffled
    by `default_rng([seed, CLIP_ROTATION_STREAM])`, that permutation repeated and cut into
    consecutive blocks of K, block j to shape j (the balanced rotation). A shape's K clips are
    distinct; every clip runs on floor(N K / C) or ceil(N K / C) shapes (C clips; with N K < C
    only the first N K of the permutation run, each on one shape). The pairs depend only on (the
    clip set, N, K, seed): every checkpoint evaluated with the same flags meets the same (shape,
    clip) pairs. K = 0 (every clip on every shape) or K >= C: every clip on every shape, in the
    given order. ValueError for N < 1 or K < 0."""
    if shapes < 1 or per_shape < 0:
        raise ValueError(f"shapes = {shapes} must be >= 1 and clips per shape = {per_shape} >= 0")
    ids = list(dict.fromkeys(clip_ids))
    if per_shape == 0 or per_shape >= len(ids):
        return [tuple(ids)] * shapes
    order = sorted(ids)
    perm = [order[i] for i in np.random.default_rng([seed, CLIP_ROTATION_STREAM]).permutation(len(order))]
    cycle = perm * -(-shapes * per_shape // len(perm))
    return [tuple(cycle[j * per_shape:(j + 1) * per_shape]) for j in range(shapes)]


SETTABLE = ("ankle_armature", "arm_armature", "pd_velocity_target", "pd_action_scale", "effort_scale", "passive_damping",
            "joint_velocity", "target_velocity_window", "alpha", "terminate_on", "reward_weights", "reward_scales",
            "reference_filter_hz", "reference_floor", "pd_target_range")
"""`ExecutorConfig` fields an evaluation may change from what the checkpoint trained with
(`--set NAME=VALUE`): the body's model, the PD, how the reference clips are cleaned, and how the
reward and the rule measure. The clip set, the split and the perturbations have options of their own."""
ONLY_FOR_ACTUATION = {"pd_velocity_target": "pd", "pd_action_scale": "pd", "effort_scale": "torque",
                      "passive_damping": "torque", "pd_target_range": "pd"}
"""`SETTABLE` fields that only one actuation reads: setting one on the other would change nothing."""


def _json_or_word(text: str) -> Any:
    """`text` as JSON, else the bare word itself (a choice such as `step_mean`)."""
    try:
        return json.loads(text)
    except (ValueError, RecursionError):  # RecursionError: nested deeper than a config value can be
        return text


def with_settings(loaded: checkpoint.Loaded, pairs: list[str]) -> checkpoint.Loaded:
    """The checkpoint with `NAME=VALUE` pairs (`SETTABLE` fields of its `ExecutorConfig`; VALUE as
    JSON, or a bare word for a choice, or comma-separated numbers for a tuple) in its task config;
    ValueError naming the pair and what is allowed. The policy is unchanged: this measures a
    trained policy on a changed body or rule, as `--zero-action` measures the PD without one."""
    if not pairs:
        return loaded
    current = dataclasses.asdict(loaded.cfg.task.executor)
    actuation, named = loaded.cfg.task.executor.actuation, set()
    for pair in pairs:
        name, sep, text = pair.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or name not in SETTABLE:
            raise ValueError(f"--set {pair!r}: give NAME=VALUE with NAME one of {', '.join(SETTABLE)}")
        if name in named:
            raise ValueError(f"--set {pair!r}: {name} is set twice; give each name once")
        if ONLY_FOR_ACTUATION.get(name, actuation) != actuation:
            raise ValueError(f"--set {pair!r}: {name} only acts on {ONLY_FOR_ACTUATION[name]} actuation and this "
                             f"checkpoint uses {actuation}, so it would change nothing")
        named.add(name)
        if isinstance(current[name], tuple) and not text.lstrip().startswith("["):
            current[name] = [_json_or_word(x.strip()) for x in text.split(",")]
        else:
            current[name] = _json_or_word(text.strip())
    try:
        ex = _from_dict(type(loaded.cfg.task.executor), current)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"--set {' '.join(pairs)}: {exc}") from None
    task = dataclasses.replace(loaded.cfg.task, executor=ex)
    return dataclasses.replace(loaded, cfg=dataclasses.replace(loaded.cfg, task=task))


def make_eval_env(loaded: checkpoint.Loaded, clips: Iterable[EvalClip], perturbation: Perturbation = Perturbation(),
                  shapes: bool = False):
    """The evaluation environment with the imported clips registered and the mass scaled; with
    `shapes`, one whose body varies (`shape_task`)."""
    env = make_env(eval_task(loaded.cfg.task, perturbation, shapes), seed=0)
    for c in clips:
        if c.clip is not None:
            env.register_clip(c.clip_id, c.clip)
    if perturbation.mass != 1.0:
        env.scale_mass(perturbation.mass)
    return env


def clip_durations(env, clips: Iterable[EvalClip]) -> dict[str, float]:
    """{clip_id: duration in s} as the environment plays each clip."""
    out = {}
    for c in clips:
        env.reset(0, env.space.default_array, clip_id=c.clip_id, start_s=0.0)
        out[c.clip_id] = float(env.scheduler.status()["clip_duration_s"])
    return out


def first_failures(terms: dict[str, float], weights, alpha: float, own_rule: str,
                   own_watch: tuple[str, ...] | None = None) -> tuple[str | None, str | None, str | None]:
    """(the per-term rule's verdict over all five terms, over the four pose terms, the
    checkpoint's own rule's verdict) at one step: the name of what ended it
    (`executor_rewards.termination`), or None."""
    per_term = rw.termination(terms, weights, "per_term", alpha)
    pose = rw.termination(terms, weights, "per_term", alpha, rw.POSE_TERMS)
    own = rw.termination(terms, weights, own_rule, alpha, own_watch or rw.TERMS)
    return per_term, pose, own


def run_episode(env, policy, clip_id: str, start_s: float, own_rule: str, seed: int,
                perturbation: Perturbation = Perturbation(), on_step: Callable[[Any, int], None] | None = None,
                max_steps: int | None = None, params: np.ndarray | None = None) -> dict[str, Any]:
    """One deterministic episode on `clip_id` from `start_s` in an `eval_task` environment;
    the record of the module docstring. `seed` seeds the projectile's directions. `max_steps`:
    stop after that many control steps (what has not failed by then counts as not failed).
    `params`: the body's shape (an environment whose body varies; default the base body).
    `on_step(env, k)` runs after step k, before the observation is acted on (a morph there
    changes the body the next action drives)."""
    ex = env.ex
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed, env.space.default_array if params is None else params, clip_id=clip_id, start_s=start_s)
    planned = int(env.scheduler.status()["steps_left"])
    rewards: list[float] = []
    joint_err: list[float] = []
    body_err: list[float] = []
    fail = {"per_term": None, "pose": None, "own": None, "phc": None}
    failed_term = None
    diverged = False
    k = 0
    while True:
        if perturbation.projectile_every and k % perturbation.projectile_every == 0:
            env.throw_projectile(perturbation.projectile_speed_mps, perturbation.projectile_distance_m, rng)
        with torch.no_grad():
            action, _ = policy.act(obs[None], deterministic=True)
        obs, r, term, trunc, info = env.step(action[0])
        k += 1
        if on_step is not None:
            seen = on_step(env, k)
            if seen is not None:  # the body changed (a morph): act on what is there now
                obs = seen
        if info.get("diverged"):
            diverged = True
            for key in fail:
                fail[key] = fail[key] or k
            failed_term = failed_term or "divergence"
            break
        rewards.append(float(r))
        joint_err.append(float(info["joint_error_m"]))
        body_err.append(float(info["body_error_m"]))
        per_term, pose, own = first_failures(info["terms"], ex.reward_weights, ex.alpha, own_rule, ex.terminate_on)
        if per_term and fail["per_term"] is None:
            fail["per_term"], failed_term = k, per_term
        if pose and fail["pose"] is None:
            fail["pose"] = k
        if own and fail["own"] is None:
            fail["own"] = k
        if info["body_error_m"] > PHC_THRESHOLD_M and fail["phc"] is None:
            fail["phc"] = k
        if term or trunc or (max_steps is not None and k >= max_steps):
            break
    own_end = min(fail["own"] or k, len(rewards))
    ret = float(sum(rewards[:own_end]))
    return {
        "clip_id": clip_id, "start_s": float(start_s), "planned_steps": planned, "steps": k,
        "success": fail["per_term"] is None, "pose_success": fail["pose"] is None, "phc_success": fail["phc"] is None,
        "fail_step": fail["per_term"], "pose_fail_step": fail["pose"], "failed_term": failed_term, "phc_fail_step": fail["phc"],
        "own_end_step": fail["own"] or k, "diverged": diverged,
        "tracked_frac": (fail["per_term"] - 1) / max(planned, 1) if fail["per_term"] else 1.0,
        "return": ret,
        "return_per_planned_step": ret / max(planned, 1),
        "reward_per_step": ret / own_end if own_end else 0.0,
        "mpjpe_mm": 1000.0 * float(np.mean(joint_err[:own_end])) if own_end else None,
        "global_mpe_mm": 1000.0 * float(np.mean(body_err[:own_end])) if own_end else None,
    }


_WORKER: dict[str, Any] = {}


def _init_worker(state_file: str, clips: list[EvalClip], perturbation: Perturbation, zero_action: bool = False,
                 cfg_json: str = "", max_steps: int | None = None, shapes: np.ndarray | None = None) -> None:
    torch.set_num_threads(1)
    loaded = checkpoint.load_trained(state_file)
    if cfg_json:  # the parent's config, with any `--set` in it
        loaded = dataclasses.replace(loaded, cfg=RunConfig.from_json(cfg_json))
    env = make_eval_env(loaded, clips, perturbation, shapes is not None)
    policy = harness.ZeroPolicy(env.act_dim) if zero_action else checkpoint.make_policy(loaded, env.obs_dim, env.act_dim)
    _WORKER.update(env=env, policy=policy, rule=loaded.cfg.task.executor.termination, perturbation=perturbation,
                   max_steps=max_steps, shapes=shapes)


def _work(job: tuple) -> dict[str, Any]:
    i, clip_id, start_s, *shape = job
    shapes = _WORKER.get("shapes")
    params = None if not shape else shapes[shape[0]]
    out = run_episode(_WORKER["env"], _WORKER["policy"], clip_id, start_s, _WORKER["rule"], seed=i,
                      perturbation=_WORKER["perturbation"], max_steps=_WORKER.get("max_steps"), params=params)
    extra = {} if not shape else {"shape_index": int(shape[0]), "shape": [float(x) for x in params]}
    return {"index": i, **out, **extra}


def episode_jobs(clips: list[EvalClip], durations: dict[str, float], starts: int,
                 shapes: int = 0, shape_clips: Sequence[Sequence[str]] | None = None) -> list[tuple]:
    """(index, clip_id, start_s) of every episode, clip-major; the index seeds the episode. With
    `shapes` N > 0, (index, clip_id, start_s, shape index) of every (clip, shape, start), clip
    then shape major (a clip's retargeting onto a body is made once and reused by its starts);
    `shape_clips` (`shape_clip_assignment`, one entry per shape): only the (clip, shape) pairs it
    lists, in the same order (every clip on every shape gives the jobs of no `shape_clips`)."""
    jobs: list[tuple] = []
    on = None if shape_clips is None else [set(ids) for ids in shape_clips]
    for c in clips:
        times = start_times(durations[c.clip_id], starts)
        if not shapes:
            jobs += [(len(jobs) + k, c.clip_id, s) for k, s in enumerate(times)]
            continue
        for j in range(shapes):
            if on is not None and c.clip_id not in on[j]:
                continue
            for s in times:
                jobs.append((len(jobs), c.clip_id, s, j))
    return jobs


def evaluate(loaded: checkpoint.Loaded, clips: list[EvalClip], starts: int, workers: int = 1,
             perturbation: Perturbation = Perturbation(), progress: Callable[[int, int], None] | None = None,
             durations: dict[str, float] | None = None, zero_action: bool = False,
             max_steps: int | None = None, shapes: np.ndarray | None = None,
             shape_clips: Sequence[Sequence[str]] | None = None) -> list[dict[str, Any]]:
    """One episode per (clip, start) (`episode_jobs`), each record tagged with its clip's label
    and split, in job order. `durations` (clip time, s) fixes the start frames; by default they
    are read from an environment at normal speed, so every perturbation row starts the same frames.
    `zero_action`: act with zeros instead of the checkpoint's policy (`harness.ZeroPolicy`);
    `max_steps`: stop every episode after that many control steps (`run_episode`). `shapes`
    `[N, P]` (`eval_shapes`): every (clip, start) on each of these bodies (`shape_task`), each
    record carrying its `shape_index` and `shape`; with `shape_clips` (`shape_clip_assignment`)
    only each body's own clips (a clip no body runs is not even loaded). The start frames are the
    base body's (a clip retargeted onto a body keeps its timing)."""
    if shapes is not None and shape_clips is not None:
        assigned = {cid for ids in shape_clips for cid in ids}
        clips = [c for c in clips if c.clip_id in assigned]
    if durations is None:
        durations = clip_durations(make_eval_env(loaded, clips), clips)
    jobs = episode_jobs(clips, durations, starts, 0 if shapes is None else len(shapes),
                        None if shapes is None else shape_clips)
    init = (str(loaded.path), list(clips), perturbation, zero_action, loaded.cfg.to_json(), max_steps,
            None if shapes is None else np.asarray(shapes, dtype=np.float64))
    results = harness.run_jobs(_init_worker, init, _work, jobs, workers, progress)
    by_id = {c.clip_id: c for c in clips}
    for r in results:
        r["label"], r["split"] = by_id[r["clip_id"]].label, by_id[r["clip_id"]].split
    return results


CEILING_STEPS = 3
"""A start whose zero-action episode fails within this many control steps is one no policy can
be expected to track (`zero_action_ceiling`)."""


def zero_action_ceiling(loaded: checkpoint.Loaded, clips: list[EvalClip], starts: int, workers: int = 1,
                        records: list[dict] | None = None, steps: int = CEILING_STEPS,
                        shapes: np.ndarray | None = None,
                        shape_clips: Sequence[Sequence[str]] | None = None) -> dict[str, Any]:
    """The starts that fail within `steps` control steps with zero actions (the PD on the
    reference itself for PD targets, no torque for torques), run for those steps only on the
    same (clip, start) jobs as `evaluate`: such a start is lost before any policy could act on
    it (the reference's pose or velocity at the start is already out of reach), so the share of
    the others is the ceiling of success. Returns {"steps", "episodes", "failed", "failed_pct",
    "ceiling_pct", "pose_failed", "pose_ceiling_pct" (the same by the pose terms), "by_split":
    {split: those}, "starts": [(clip_id, start_s)] of the failed ones}, and with the policy's
    `records` of the same jobs "policy_success_on_failed": how many of those the policy tracked.
    `shapes`, `shape_clips`: the same jobs on those bodies (`evaluate`)."""
    zero = evaluate(loaded, clips, starts, workers, zero_action=True, max_steps=steps, shapes=shapes,
                    shape_clips=shape_clips)

    def agg(rs: list[dict]) -> dict[str, Any]:
        n = len(rs)
        bad = sum(r["fail_step"] is not None and r["fail_step"] <= steps for r in rs)
        pose_bad = sum(r["pose_fail_step"] is not None and r["pose_fail_step"] <= steps for r in rs)
        return {"episodes": n, "failed": bad, "failed_pct": 100.0 * bad / n if n else None,
                "ceiling_pct": 100.0 * (n - bad) / n if n else None, "pose_failed": pose_bad,
                "pose_ceiling_pct": 100.0 * (n - pose_bad) / n if n else None}

    out: dict[str, Any] = {"steps": steps, **agg(zero)}
    by_split: dict[str, list[dict]] = defaultdict(list)
    for r in zero:
        by_split[r["split"]].append(r)
    out["by_split"] = {k: agg(by_split[k]) for k in SPLITS if k in by_split}
    failed = [r for r in zero if r["fail_step"] is not None and r["fail_step"] <= steps]
    out["starts"] = [(r["clip_id"], r["start_s"], *([r["shape_index"]] if "shape_index" in r else [])) for r in failed]
    if records is not None:
        by_index = {r["index"]: r for r in records}
        out["policy_success_on_failed"] = sum(bool(by_index[r["index"]]["success"]) for r in failed if r["index"] in by_index)
    return out


# ---- aggregates ----


def _mean(xs: list) -> float | None:
    xs = [x for x in xs if x is not None]
    return float(np.mean(xs)) if xs else None


def stats(records: list[dict]) -> dict[str, Any]:
    """Aggregates of a group of episodes, each episode weighing the same: success and PHC
    success %, MPJPE and global error (mm, over every episode as the checkpoint runs it, and
    MPJPE over the successful ones, as PHC reports both), mean reward per step, mean return,
    performance (mean return per planned step: the robustness measure), the mean tracked share
    of the clip (%), and how often each term ended an episode."""
    ok = [r for r in records if r["success"]]
    return {
        "episodes": len(records),
        "clips": len({r["clip_id"] for r in records}),
        "success_pct": 100.0 * len(ok) / len(records) if records else None,
        "pose_success_pct": 100.0 * sum(r.get("pose_success", False) for r in records) / len(records) if records else None,
        "phc_success_pct": 100.0 * sum(r["phc_success"] for r in records) / len(records) if records else None,
        "mpjpe_mm": _mean([r["mpjpe_mm"] for r in records]),
        "mpjpe_mm_success": _mean([r["mpjpe_mm"] for r in ok]),
        "global_mpe_mm": _mean([r["global_mpe_mm"] for r in records]),
        "reward_per_step": _mean([r["reward_per_step"] for r in records]),
        "mean_return": _mean([r["return"] for r in records]),
        "performance": _mean([r["return_per_planned_step"] for r in records]),
        "tracked_pct": 100.0 * _mean([r["tracked_frac"] for r in records]) if records else None,
        "diverged": sum(r["diverged"] for r in records),
        "failed_terms": dict(Counter(r["failed_term"] for r in records if r["failed_term"]).most_common()),
    }


def group_stats(records: list[dict], key) -> dict[str, dict[str, Any]]:
    """{value of `key` (clip_id, label or split; or a function of the record): `stats`} in
    first-seen order; a record whose key is None is left out."""
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in records:
        k = key(r) if callable(key) else r[key]
        if k is not None:
            groups[k].append(r)
    return {k: stats(v) for k, v in groups.items()}


def content_and_style(label: str) -> tuple[str, str] | None:
    """(content, style) of a two-level labelled take (`root/bandai/<content>/<style>`, the Bandai
    Namco library's labels), None for another label."""
    parts = label.split("/")
    if len(parts) == 4 and "/".join(parts[:2]) == bandai.LABEL_PREFIX:
        return parts[2], parts[3]
    return None


def by_split(records: list[dict], level: int) -> dict[str, dict[str, dict[str, Any]]]:
    """{content (level 0) or style (level 1): {split: `stats`}} over the two-level labelled takes,
    sorted by name; empty when no record is one."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for split in SPLITS:
        part = [r for r in records if r["split"] == split]
        for name, s in group_stats(part, lambda r: (content_and_style(r["label"]) or (None, None))[level]).items():
            out.setdefault(name, {})[split] = s
    return dict(sorted(out.items()))


def summarize(records: list[dict], clips: list[EvalClip], space: ParamSpace | None = None) -> dict[str, Any]:
    """Per clip (with its label and split), per class (label), per split (in `SPLITS` order),
    per content and per style of the two-level labelled takes (each by split), and overall;
    with records on shapes (`evaluate(..., shapes=...)`) and their `space`, also per shape
    (`shape_summary`)."""
    per_clip = group_stats(records, "clip_id")
    meta = {c.clip_id: c for c in clips}
    for cid, s in per_clip.items():
        s.update(label=meta[cid].label, split=meta[cid].split, **({"source": meta[cid].source} if meta[cid].source else {}))
    splits = group_stats(records, "split")
    out = {
        "overall": stats(records),
        "splits": {k: splits[k] for k in SPLITS if k in splits},
        "classes": dict(sorted(group_stats(records, "label").items())),
        "contents": by_split(records, 0),
        "styles": by_split(records, 1),
        "clips": per_clip,
    }
    if space is not None and any("shape_index" in r for r in records):
        out["shapes"] = shape_summary(records, space)
    return out


EXTREME_SHARE = 0.1
"""The share of the shapes farthest from the base body (`extremeness`) the summary reports apart."""
WORST_SHARE = 0.1
"""The worst decile of the success map (`worst_decile`): this share of the shapes, lowest success first."""
NEIGHBOUR_SHARE = 0.05
"""`worst_decile` reads the success map at a shape as the pooled success of this share of the
shapes nearest it (itself included): 15 of 300 shapes, 60 episodes at 2 clips x 2 starts each."""


def share_count(share: float, n: int) -> int:
    """How many of `n` shapes a `share` of them is: rounded, at least one."""
    return max(1, int(round(share * n)))


def worst_decile(records: list[dict], space: ParamSpace | None = None) -> dict[str, dict[str, Any]]:
    """The worst decile of the success map, overall and per split: {"overall" | split:
    {"success_pct", "shapes" (their indices), "of"}}.

    The map is read at every evaluated shape as the pooled success of the episodes on its
    `NEIGHBOUR_SHARE` nearest shapes (itself included; distances in parameters scaled to the
    box, `space`; without a space or a record's "shape", each shape alone); the `WORST_SHARE` of
    the shapes where it is lowest are the worst decile, and its figure is the mean of their map
    values. Each shape is one uniform draw from the whole box, so this is the lowest tenth of the
    map over every shape parameter whatever --map-params and --bins draw. The neighbourhood is
    what makes it a map: with 2 clips x 2 starts per shape, a shape alone has 4 episodes, and the
    lowest tenth of 300 such shapes was 0% for every checkpoint (the shapes that drew two hard
    clips). Per group: the shapes that ran some clip of that group, pooled over their episodes of
    it; ties ranked by index."""
    groups: dict[str, dict[int, list[bool]]] = defaultdict(lambda: defaultdict(list))
    where: dict[int, np.ndarray] = {}
    for r in records:
        j = int(r["shape_index"])
        for name in ("overall", r["split"]):
            groups[name][j].append(bool(r["success"]))
        if space is not None and "shape" in r:
            where[j] = (np.asarray(r["shape"], float) - space.low_array) / np.maximum(space.high_array - space.low_array, 1e-12)
    out: dict[str, dict[str, Any]] = {}
    for name in ("overall", *SPLITS):
        if name not in groups:
            continue
        shapes = sorted(groups[name])
        hits = np.array([sum(groups[name][j]) for j in shapes], float)
        counts = np.array([len(groups[name][j]) for j in shapes], float)
        k = share_count(NEIGHBOUR_SHARE, len(shapes)) if len(where) == len(groups["overall"]) else 1
        if k > 1:
            pts = np.stack([where[j] for j in shapes])
            near = np.argsort(((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1), axis=1, kind="stable")[:, :k]
            value = 100.0 * hits[near].sum(1) / counts[near].sum(1)
        else:
            value = 100.0 * hits / counts
        ranked = sorted(zip(value.tolist(), shapes))
        worst = ranked[: share_count(WORST_SHARE, len(ranked))]
        out[name] = {"success_pct": float(np.mean([x for x, _ in worst])), "shapes": sorted(j for _, j in worst),
                     "of": len(ranked), "neighbours": k}
    return out


def shape_summary(records: list[dict], space: ParamSpace) -> dict[str, Any]:
    """Per shape: its parameters (name -> value), `extremeness` and `stats` over every (clip,
    start) on it, in shape order ("per_shape"); the spread of per-shape success and PHC success
    (min, median, max %) and `stats` over the most extreme `EXTREME_SHARE` of the shapes and over
    the rest ("extreme", "rest"), each by split too; the worst decile of the success map
    (`worst_decile`): its success % per group ("worst_decile_shape_success_pct": {"overall" |
    split: %}, the figure to compare checkpoints by) and the shapes behind each ("worst_decile_shapes")."""
    groups: dict[int, list[dict]] = defaultdict(list)
    for r in records:
        groups[int(r["shape_index"])].append(r)
    order = sorted(groups)
    params = np.array([groups[j][0]["shape"] for j in order])
    ext = extremeness(space, params)
    per_shape = []
    for j, e in zip(order, ext):
        row = {"index": j, "params": dict(zip(space.names, map(float, groups[j][0]["shape"]))), "extremeness": float(e),
               **stats(groups[j])}
        per_shape.append(row)
    k = share_count(EXTREME_SHARE, len(order))
    extreme = {order[i] for i in np.argsort(ext)[::-1][:k]}

    worst = worst_decile(records, space)

    def spread(key: str) -> dict[str, float]:
        xs = [row[key] for row in per_shape]
        return {"min": float(np.min(xs)), "median": float(np.median(xs)), "max": float(np.max(xs))}

    def part(rs: list[dict]) -> dict[str, Any]:
        split = group_stats(rs, "split")
        return {**stats(rs), "splits": {s: split[s] for s in SPLITS if s in split}}

    return {
        "names": list(space.names), "low": [float(x) for x in space.low], "high": [float(x) for x in space.high],
        "base": [float(x) for x in space.default_array], "count": len(order),
        "success_pct": spread("success_pct"), "phc_success_pct": spread("phc_success_pct"),
        "extreme_share": EXTREME_SHARE, "extreme_shapes": sorted(extreme),
        "extreme": part([r for r in records if r["shape_index"] in extreme]),
        "rest": part([r for r in records if r["shape_index"] not in extreme]),
        "worst_share": WORST_SHARE,
        "worst_decile_shape_success_pct": {g: w["success_pct"] for g, w in worst.items()},
        "worst_decile_shapes": {g: {"shapes": w["shapes"], "of": w["of"], "neighbours": w["neighbours"]}
                                for g, w in worst.items()},
        "per_shape": per_shape,
    }
