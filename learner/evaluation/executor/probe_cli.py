"""What the executor probes (`morphmimic velocity-probe`, `morphmimic break-probe`) share: the
options that pick a checkpoint, its clips and a changed body, the environment and policy they
open, the loop over every split's episodes, and where the table goes."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, ClassVar, Literal

from common.config_limits import Limit, at_least, check_limits, validated
from learner import checkpoint
from learner.cli_options import refuse
from learner.evaluation.executor import evaluate as xe
from learner.evaluation.executor.report import Settings

Split = Literal["train", "test", "unused"]


@validated
@dataclass(kw_only=True)
class ProbeOptions:
    """The options every probe takes (`morphmimic velocity-probe`, `morphmimic break-probe`)."""

    checkpoint: str
    """Checkpoint dir, state.pt or run dir of an executor run."""
    starts: int = 10
    """Start frames per clip (the evaluation's)."""
    splits: tuple[Split, ...] = ("train", "test")
    """The splits whose clips are probed."""
    out: str = ""
    """Output directory (default: none, print only)."""
    settings: Settings = ()

    LIMITS: ClassVar[dict[str, Limit]] = {"starts": at_least(1)}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        if not self.splits:
            raise ValueError("--splits: give one or more of train, test, unused")
        check_limits(self)


@dataclass
class Opened:
    """A probe's checkpoint (with `--set` applied), its clips, an evaluation env and the policy."""

    loaded: Any
    clips: list
    env: Any
    policy: Any
    title: str  # the run's name, with the settings changed


UNREAD_SETTINGS = ("terminate_on", "reward_weights")
"""`--set` fields no probe figure depends on (they only weigh the return or pick the checkpoint's
own rule; every probe reads the five terms against alpha itself)."""


def open_checkpoint(prog: str, args: ProbeOptions) -> Opened:
    """Load `args.checkpoint`; a usage error of `prog` (exit 2) naming the value when it is no
    executor, a `--set` pair is bad or changes nothing the probe reads, a split holds no clips or
    `--out` cannot be written, before any episode runs. Repeated `--splits` are run once."""
    args.splits = tuple(dict.fromkeys(args.splits))
    if args.out:
        try:
            Path(args.out).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            refuse(prog, f"--out {args.out}: cannot make that folder ({exc.strerror or exc})")
    unread = [pair for pair in args.settings if pair.partition("=")[0].strip().replace("-", "_") in UNREAD_SETTINGS]
    if unread:
        refuse(prog, f"--set {' '.join(unread)}: no figure of the probe depends on {', '.join(UNREAD_SETTINGS)}")
    loaded = checkpoint.load_trained(args.checkpoint)
    if loaded.cfg.task.name != "executor":
        refuse(prog, f"--checkpoint {args.checkpoint} is a {loaded.cfg.task.name!r} checkpoint; the probe needs an executor")
    try:
        loaded = xe.with_settings(loaded, list(args.settings))
    except ValueError as exc:
        refuse(prog, str(exc))
    clips = xe.default_clips(loaded.cfg.task, args.splits)
    empty = [s for s in args.splits if not any(c.split == s for c in clips)]
    if empty:
        refuse(prog, f"--splits {' '.join(empty)}: no clip of {loaded.cfg.name} is in that split")
    env = xe.make_eval_env(loaded, clips)
    policy = checkpoint.make_policy(loaded, env.obs_dim, env.nu)
    title = loaded.cfg.name + (f" with --set {' '.join(args.settings)}" if args.settings else "")
    return Opened(loaded, clips, env, policy, title)


class StepHook:
    """A probe's `on_step` hook for one episode: `step(env, terms, k)` sees each step's five reward
    terms once. A step that diverged is skipped: it leaves the last step's terms in `env.last_terms`
    (or reset's empty ones on the first step)."""

    def __init__(self) -> None:
        self._seen: dict | None = None

    def __call__(self, env, k: int) -> None:
        terms = env.last_terms
        if not terms or terms is self._seen:
            return
        self._seen = terms
        self.step(env, terms, k)

    def step(self, env, terms: dict[str, float], k: int) -> None:
        raise NotImplementedError


def episodes(opened: Opened, split: str, starts: int, make_hook: Callable[[Any], Any]):
    """Yield (hook, record) for every episode of `split` (each clip from `starts` start frames, the
    mean action, `executor_eval.run_episode`), `make_hook(env)` making each episode's `on_step`."""
    clips = [c for c in opened.clips if c.split == split]
    durations = xe.clip_durations(opened.env, clips)
    for clip in clips:
        for start in xe.start_times(durations[clip.clip_id], starts):
            hook = make_hook(opened.env)
            # the rule only sets rec["return"]; every verdict is read off the five terms
            yield hook, xe.run_episode(opened.env, opened.policy, clip.clip_id, start, "per_term", 0, on_step=hook)


def write(out: str, stem: str, text: str, payload: dict) -> None:
    """`<out>/<stem>.md` and `.json` (nothing when `out` is empty)."""
    if not out:
        return
    folder = Path(out)  # made (or refused) by `open_checkpoint`
    (folder / f"{stem}.md").write_text(text)
    (folder / f"{stem}.json").write_text(json.dumps(payload, indent=1) + "\n")
