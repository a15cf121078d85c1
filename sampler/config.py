"""Configuration of the sampler service (one frozen dataclass, composed into the run config)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

from common.config_limits import PORT, Limit, above, at_least, between, check_limits, validated

MIN_TIME_BIN_S = 0.05
"""Narrowest time bin: a few control steps (finer bins only spread the same failures thinner)."""


@dataclass(frozen=True)
@validated
class SamplerConfig:
    """Adaptive sampling of task/shape parameters (Won & Lee 2019, Sec. 4.2 and Algorithm 1) and
    the hierarchical motion balancer (UniCon 2020, Sec. 5.1). Defaults are the paper's where it
    gives a number (Table 2: N_mcmc, P_mcmc, learning rates)."""

    k: float = 5.0
    """Uniformity knob of the target density exp(-k * Vm / Vbar); 0 = plain uniform sampling (the
    baseline). The paper compares several k (its Figure 6) without a readable default."""
    p_mcmc: int = 20
    """Policy iterations (ticks) between MCMC refills of the shape buffer (paper: P_mcmc = 20)."""
    n_mcmc: int = 1000
    """Shapes in the buffer that episodes draw from (paper: N_mcmc = 1000)."""
    n_chains: int = 32
    """Independent Metropolis-Hastings chains run side by side (vectorized) per refill."""
    burn_in: int = 100
    """MH steps per chain discarded before the first kept sample."""
    thin: int = 4
    """Keep every `thin`-th MH step of each chain after burn-in (reduces autocorrelation)."""
    clip_k: float = 0.0
    """Adaptive clip sampling (`sampler/clip_outcomes.py`): the motion balancer's probability of
    each clip times exp(-clip_k r), r the share of its recent training segments tracked to its
    end; 0 = UniCon's balancer alone."""
    clip_weighting: Literal["exp", "failure"] = "exp"
    """How a clip's recent outcomes reweight its balancer probability (`sampler/clip_outcomes.py`):
    exp = exp(-clip_k r) (clip_k 0: the balancer alone, the default); failure = max(clip_floor,
    1 - r), the recent failure share with a floor, so every clip keeps at least clip_floor times
    its class-tree share."""
    clip_floor: float = 0.1
    """Smallest factor of a clip under `clip_weighting failure` (a clip the policy always tracks
    is still drawn at this fraction of its class-tree share; every class stays in play)."""
    clip_memory: float = 0.95
    """At each tick that brings new counts, the weight the clip counts so far keep against them
    (0.95: about the last 20 reported iterations count; a tick without a report forgets nothing)."""
    time_bin_s: float = 0.0
    """Failure-weighted start times (`sampler/time_bins.py`, BeyondMimic/mjlab adaptive sampling):
    each clip cut into bins of this many seconds (0.25-0.5 s suits 1-5 s clips), starts drawn by
    the recent failures in and after each bin; 0 = off, uniform starts drawn by the environment.
    Needs a task whose clips have lengths (the executor) and episodes that begin where the draw
    says (`--task.executor.at-clip-end stop` makes every episode's clip and start the sampler's)."""
    time_kernel: int = 3
    """Bins before a failure's own that it also raises (the look-back kernel), so starts land
    before the failure, where the policy can still recover (mjlab: 2, of 1 s bins)."""
    time_lambda: float = 0.8
    """Decay of the look-back kernel per bin: bin b - j gets lambda^j of a failure at bin b (mjlab: 0.8)."""
    time_uniform: float = 0.1
    """Share of a clip's starts drawn uniformly over its time whatever the failures (mjlab: 0.1),
    so no stretch of a clip is forgotten."""
    shape_by_class: bool = False
    """Shape and motion class drawn together (issue 55 item 2): Vm is fitted over (shape, class),
    the class a clip's label cut to `class_depth` levels below the root, and each class keeps its
    own buffer of `n_mcmc` shapes drawn from exp(-k Vm(s, c) / Vbar_c). The balancer still picks
    each episode's clip (every class stays in play); its shape comes from its class's buffer.
    Needs a task with clips and value reports that name each pair's clip. Off: one buffer, Vm
    over shapes alone."""
    class_depth: int = 2
    """Label levels below the root that make a class of `shape_by_class` (2: `root/bandai/walk`,
    the level of the per-class clip metrics; 1: `root/bandai`)."""
    vbar_floor: float = 1e-3
    """Smallest |Vbar| used as the density's temperature: guards the division early in training."""
    vm_hidden: tuple[int, ...] = (64, 64)
    """Hidden layer sizes of the marginal value MLP Vm(s_b) (ReLU)."""
    vm_lr: float = 1e-3
    """Adam learning rate of Vm (paper Table 2: marginal value learning rate 1e-3)."""
    vbar_rate: float = 1e-3
    """Step size of the running average Vbar per minibatch (paper Table 2: 1e-3)."""
    vm_fit_steps: int = 64
    """Adam steps of Vm per tick. The paper does 10 epochs of 128-pair minibatches over 4096
    tuples (320 steps); on a CPU each step costs ~1 ms of overhead whatever its size, so the
    default passes about the same data (64 x 512 = 8 epochs) in a fifth of the time."""
    vm_minibatch: int = 512
    """Pairs per Vm minibatch (paper: 128, as for PPO; see vm_fit_steps)."""
    max_pending_pairs: int = 65536
    """Most (params, V) pairs held between ticks; the oldest are dropped beyond it."""
    max_draw: int = 65536
    """Largest `n` one draw request may ask for; bigger requests get an error reply."""
    probe_points: int = 1024
    """Uniform points over the box on which Vm's min/max/mean are reported after each fit."""
    seed: int = 0
    """Seed of the sampler's numpy generator and of Vm's initial weights."""
    plot_params: tuple[str, ...] = ()
    """The two parameters of the Vm map PNG; empty = the first two of the space."""
    device: Literal["cpu", "cuda", "auto"] = "cpu"
    """Device of the marginal value fit; the training process sets it to `--learner.device`."""
    host: str = "127.0.0.1"
    """Interface the ROUTER binds; "auto" (Ray actor only) = this node's IP for a cluster."""
    port: int = 0
    """TCP port of the ROUTER; 0 = a free port chosen at bind time."""
    state_dir: str = ""
    """Where the service keeps its own state file (`sampler/state_file.py`), saved every
    `state_every_s` and on stop, and restored when it starts again (a killed and restarted
    sampler comes back as it last saved). Empty: no file; the training process sets
    `<run>/sampler` when the sampler runs on this machine."""
    state_every_s: float = 10.0
    """Seconds between two saves of the state file while requests change the state."""

    FLAG_PREFIX: ClassVar[str] = "sampler"
    LIMITS: ClassVar[dict[str, Limit]] = {
        "k": at_least(0, False), "clip_k": between(0, 50), "clip_memory": between(0, 1, hi_open=True),
        "clip_floor": between(0, 1, lo_open=True), "time_bin_s": between(0, 10), "time_kernel": between(0, 20, integer=True),
        "time_lambda": between(0, 1), "class_depth": between(1, 16, integer=True), "time_uniform": between(0, 1, lo_open=True), "p_mcmc": at_least(1), "n_mcmc": at_least(1), "n_chains": at_least(1), "burn_in": at_least(0),
        "thin": at_least(1), "vbar_floor": above(0), "vm_hidden": at_least(1), "vm_lr": above(0),
        "vbar_rate": between(0, 1, lo_open=True), "vm_fit_steps": at_least(0), "vm_minibatch": at_least(1),
        "max_pending_pairs": at_least(1), "max_draw": at_least(1), "probe_points": at_least(1), "seed": at_least(0),
        "port": PORT, "state_every_s": between(0.1, 3600),
    }
    """Allowed values of the numeric fields (`common.config_limits`)."""

    def validate(self) -> None:
        """ValueError naming the first value outside what is allowed."""
        check_limits(self)
        if not self.vm_hidden:
            raise ValueError(f"--sampler.vm-hidden = {self.vm_hidden!r}: give one or more layer sizes")
        if self.device not in ("cpu", "cuda", "auto"):
            raise ValueError(f"--sampler.device = {self.device!r}: give cpu, cuda or auto")
        if self.clip_weighting not in ("exp", "failure"):
            raise ValueError(f"--sampler.clip-weighting = {self.clip_weighting!r}: give exp or failure")
        if 0 < self.time_bin_s < MIN_TIME_BIN_S:
            raise ValueError(f"--sampler.time-bin-s = {self.time_bin_s!r} is not allowed: give 0 (off) or a bin "
                             f"of at least {MIN_TIME_BIN_S} s")

    @property
    def mh_steps(self) -> int:
        """MH steps per chain for one refill: burn-in plus enough thinned steps for `n_mcmc`."""
        per_chain = -(-self.n_mcmc // self.n_chains)
        return self.burn_in + per_chain * self.thin
