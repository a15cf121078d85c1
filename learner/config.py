"""The run configuration: one frozen dataclass per service, composed into `RunConfig` (named
presets live in `learner.presets`). `python -m learner.main --preset NAME --ppo.lr 1e-4 ...` starts from a preset and
overrides any field; `--help` lists every option with its docstring (tyro)."""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from typing import ClassVar, Literal, get_args, get_origin, get_type_hints

from actors.config import ActorConfig
from common.config_limits import SEED, Limit, above, at_least, between, check_limits, validated
from common.motion.retarget_config import RetargetConfig
from common.policy import PolicyConfig
from common.tasks.base import TaskConfig
from common.tasks.body_config import BodyConfig
from common.tasks.executor.config import ExecutorConfig
from common.tasks.registry import TASKS
from common.tasks.shape.config import ImitateConfig
from learner.ppo import PPOConfig
from sampler.config import SamplerConfig


@dataclass(frozen=True)
@validated
class LearnerConfig:
    """Where the PPO update runs: the device, and how many data-parallel processes share it."""

    device: Literal["cpu", "cuda", "auto"] = "cpu"
    """cpu; cuda (refused in one line on a node without a GPU); auto: cuda when this node has
    one, else cpu. PPO, the observation normalizer and the sampler's marginal value fit run on
    it; the weights go to the actors as CPU arrays whatever it is."""
    replicas: int = 1
    """Data-parallel learner processes (`learner.replicas`): this one plus replicas - 1 Ray
    actors (one GPU each with cuda), averaging gradients with torch.distributed every minibatch
    step. Needs Ray (not --mode serial) and a minibatch that divides by it."""
    threads: int = 0
    """Torch threads of each learner process; 0: the cores this machine has left after the local
    actors, shared among the local replicas (at least 1). NOTE: more threads than free cores
    makes OpenMP spin against the actors."""
    sync_timeout_s: float = 120.0
    """A replica that has not joined an all-reduce after this long ends the run (with a checkpoint)."""

    FLAG_PREFIX: ClassVar[str] = "learner"
    LIMITS: ClassVar[dict[str, Limit]] = {
        "replicas": between(1, 1024, integer=True), "threads": at_least(0), "sync_timeout_s": above(0),
    }
    """Allowed values of the numeric fields (`common.config_limits`)."""

    def validate(self) -> None:
        """ValueError naming the first value outside what is allowed."""
        check_limits(self)
        if self.device not in ("cpu", "cuda", "auto"):
            raise ValueError(f"--learner.device = {self.device!r}: give cpu, cuda or auto")


@dataclass(frozen=True)
@validated
class RunConfig:
    name: str = "reach"
    """Run name: outputs go to `<runs_dir>/<name>/`."""
    runs_dir: str = "runs"
    """Parent directory of run directories."""
    mode: Literal["auto", "cluster", "local", "serial"] = "auto"
    """auto: attach to a running Ray cluster if one is found (RAY_ADDRESS, or `ray start` on this
    machine), else start a private local one; cluster: attach or fail; local: always a private
    instance; serial: one process, no Ray."""
    ray_address: str = ""
    """Ray cluster address to attach to (overrides RAY_ADDRESS and auto-detection)."""
    bind_host: str = ""
    """Interface the learner's sockets bind; empty: 127.0.0.1 when every node is on this machine,
    else this node's IP."""
    port_base: int = 0
    """0: every socket binds a free port (printed at start). N: the learner binds N (unrolls),
    N+1 (weights PUB), N+2 (weight snapshots) and the sampler N+3: for firewalled clusters."""
    total_env_steps: int = 400_000
    """Step budget: training stops after this many environment steps."""
    max_iterations: int = 0
    """Stop after this many policy iterations (0: no limit besides the step budget)."""
    steps_per_iteration: int = 4096
    """Transitions per PPO update (Won & Lee 2019: 4096)."""
    max_policy_lag: int = 2
    """Unrolls made by weights more than this many versions old are dropped (and counted)."""
    seed: int = 0
    """Seed of the learner, actors (seed + actor id) and sampler."""
    resume: str = "auto"
    """auto: continue from the newest loadable checkpoint of this run if any; never: start over
    (refuses to overwrite an existing run's checkpoints); or a path to a checkpoint directory."""
    init_from: str = ""
    """Fine-tune: a checkpoint (directory, state.pt, run directory or `learner/pretrained/<name>`)
    of the same task and network whose policy, value function and adaptive step size start this run;
    the optimizer's moments, counters and sampler start fresh (`learner.fine_tune`). Ignored when the run resumes a
    checkpoint of its own. Empty: start from random weights."""
    checkpoint_every: int = 10
    """Write a checkpoint every this many iterations (and always at the end)."""
    keep_checkpoints: int = 3
    """Keep only the newest this many checkpoints."""
    value_pairs_per_iteration: int = 4096
    """(parameters, V(s)) pairs sent to the sampler per iteration for the marginal value fit: the
    paper fits Vm on every tuple of the iteration (4096); `sampler.vm_fit_steps` x
    `sampler.vm_minibatch` = 64 x 512 then passes over them about 8 times. (It was 512: 64 passes
    over 512 correlated pairs, re-standardized on them every iteration, made Vm noisy.)"""
    vm_plot_every: int = 20
    """Write the sampler's Vm map PNG every this many iterations (0: only at the end)."""
    actor_max_restarts: int = -1
    """Ray restarts a crashed rollout actor up to this many times (-1: always, including when a
    lost node's capacity returns)."""
    stall_timeout_s: float = 20.0
    """An actor that sent neither unroll nor heartbeat for this long is counted as stalled and
    excluded until it sends again."""
    quiet: bool = False
    """Write progress only to log.txt and the scalar logger, not the console."""
    logger: Literal["tensorboard", "wandb"] = "tensorboard"
    """Where every metric goes as a scalar: tensorboard (`<run>/tb/`), or wandb (`<run>/wandb/`;
    the optional extra `pip install -e ".[wandb]"`; offline unless WANDB_MODE is set)."""
    curve: bool = True
    """Authenticate and encrypt every ZeroMQ socket with CURVE, with keys made for this run and
    handed to actors and sampler through Ray: a peer without them is refused and counted
    (`common.curve_keys`). `--no-curve` only to measure what it costs or to debug the wire."""
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    task: TaskConfig = field(default_factory=TaskConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    actors: ActorConfig = field(default_factory=ActorConfig)
    sampler: SamplerConfig = field(default_factory=SamplerConfig)

    FLAG_PREFIX: ClassVar[str] = ""
    LIMITS: ClassVar[dict[str, Limit]] = {
        "port_base": between(0, 65532, integer=True), "total_env_steps": at_least(1), "max_iterations": at_least(0),
        "steps_per_iteration": at_least(1), "max_policy_lag": at_least(0), "seed": SEED,
        "checkpoint_every": at_least(1), "keep_checkpoints": at_least(1), "value_pairs_per_iteration": at_least(0),
        "vm_plot_every": at_least(0), "actor_max_restarts": at_least(-1), "stall_timeout_s": above(0),
    }
    """Allowed values of the numeric fields (`common.config_limits`)."""

    def validate(self) -> None:
        """ValueError naming the first value outside what is allowed."""
        check_limits(self)
        if self.ppo.minibatch > self.steps_per_iteration:
            raise ValueError(
                f"--ppo.minibatch {self.ppo.minibatch} exceeds --steps-per-iteration {self.steps_per_iteration}"
            )
        self.task.substeps  # noqa: B018 - validates sim_hz / control_hz
        if self.sampler.time_bin_s > 0 and self.task.name in TASKS and not TASKS[self.task.name].durations:
            raise ValueError(f"--sampler.time-bin-s {self.sampler.time_bin_s:g} needs clips with start times; task "
                             f"{self.task.name!r} has none: give 0, or a task with clips (executor)")
        if self.sampler.device not in ("cpu", self.learner.device):
            raise ValueError(f"--sampler.device {self.sampler.device} is set from --learner.device ({self.learner.device}): "
                             "give --learner.device instead")
        replicas = self.learner.replicas
        if replicas > 1 and self.mode == "serial":
            raise ValueError(f"--learner.replicas {replicas} needs Ray: give --mode auto, local or cluster, not serial")
        if self.ppo.minibatch % replicas:
            raise ValueError(f"--ppo.minibatch {self.ppo.minibatch} does not divide among --learner.replicas {replicas}: "
                             "give a minibatch that is a multiple of the replicas")

    @property
    def resolved_learner_threads(self) -> int:
        """Torch threads of each learner process (`--learner.threads`, or what is left of this machine)."""
        if self.learner.threads > 0:
            return self.learner.threads

        local_actors = self.actors.num_actors * self.actors.num_cpus if self.mode != "cluster" else 0
        local_learners = self.learner.replicas if self.mode != "cluster" else 1
        return max(1, int((os.cpu_count() or 1) - local_actors) // local_learners)

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, sort_keys=True)

    @staticmethod
    def from_json(text: str) -> "RunConfig":
        """A saved configuration (a checkpoint's); ValueError naming what is wrong with it,
        whatever its JSON holds (a value out of range, of another type, a section that is not one)."""
        try:
            raw = json.loads(text)
            if not isinstance(raw, dict):
                raise ValueError(f"expected a JSON object, got {type(raw).__name__}")
            return _from_dict(RunConfig, raw)
        except ValueError:
            raise
        except Exception as exc:  # noqa: BLE001 - a wrong type anywhere in someone else's file
            raise ValueError(f"saved configuration is not a RunConfig ({type(exc).__name__}: {exc})") from None


_NESTED = {"learner": LearnerConfig, "task": TaskConfig, "policy": PolicyConfig, "ppo": PPOConfig, "actors": ActorConfig, "sampler": SamplerConfig,
           "executor": ExecutorConfig, "body": BodyConfig, "imitate": ImitateConfig, "retarget": RetargetConfig}
"""Fields that hold a config dataclass (by field name), rebuilt from their JSON objects."""

_FLAT_RETARGET = {"retarget_root_height": "root_height", "retarget_body_clearance_m": "body_clearance_m"}
"""Retargeting settings an `imitate` section held as its own fields before it nested a
`RetargetConfig` (old name -> `retarget` field)."""


def _task_sections(raw: dict) -> dict:
    """A task config in the flat layout (one TaskConfig without `body` and `imitate` sections):
    its body and shape-task keys move into `body` and `imitate`, so the shipped checkpoints and
    runs saved in that layout load with the settings they were trained with."""
    raw = dict(raw)
    for section, names in (("body", _field_names(BodyConfig)), ("imitate", _field_names(ImitateConfig) | set(_FLAT_RETARGET))):
        moved = {name: raw.pop(name) for name in names if name in raw}
        if moved:
            raw[section] = {**moved, **raw.get(section, {})}
    return raw


def _field_names(cls: type) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)}


def _nest_retarget(raw: dict) -> dict:
    """An `imitate` section written with the flat retargeting fields (`_FLAT_RETARGET`): their
    values move into its `retarget` section, so older checkpoints load with the rule and
    clearance they were trained with."""
    raw = dict(raw)
    moved = {new: raw.pop(old) for old, new in _FLAT_RETARGET.items() if old in raw}
    if moved:
        nested = raw.get("retarget")
        raw["retarget"] = {**moved, **(nested if isinstance(nested, dict) else {})}
    return raw


def _from_dict(cls: type, raw: dict):
    """`cls(**raw)` with nested config dataclasses rebuilt and JSON lists turned back into tuples;
    keys the class no longer has (a config written by an older version) are dropped."""
    names = {f.name for f in dataclasses.fields(cls)}
    if cls is TaskConfig:
        raw = _task_sections(raw)
    if cls is ImitateConfig:
        raw = _nest_retarget(raw)
    kwargs = {}
    for k, v in raw.items():
        if k not in names:
            continue
        if k in _NESTED and isinstance(v, dict):
            v = _from_dict(_NESTED[k], v)
        elif isinstance(v, list):
            v = tuple(tuple(x) if isinstance(x, list) else x for x in v)
        kwargs[k] = v
    cfg = cls(**kwargs)  # the class's own checks first (their messages are more specific)
    prefix = getattr(cls, "FLAG_PREFIX", "")
    for name, hint in get_type_hints(cls).items():  # then every Literal and bool field (tyro checks flags)
        flag = f"--{prefix + '.' if prefix else ''}{name.replace('_', '-')}"
        if get_origin(hint) is Literal and getattr(cfg, name) not in get_args(hint):
            raise ValueError(f"{flag} = {getattr(cfg, name)!r} is not one of {', '.join(map(str, get_args(hint)))}")
        if hint is bool and not isinstance(getattr(cfg, name), bool):
            raise ValueError(f"{flag} = {getattr(cfg, name)!r} is not one of true, false")
        if hint is str and not isinstance(getattr(cfg, name), str):
            raise ValueError(f"{flag} = {getattr(cfg, name)!r} is not allowed: give a string")
    return cfg
