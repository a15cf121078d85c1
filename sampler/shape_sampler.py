"""`ShapeSampler`: what each new episode is about (Won & Lee 2019, Algorithm 1; UniCon 2020, Sec. 5.1).

Ties together a task's parameter space, the marginal value function Vm and its average Vbar,
the MCMC buffer of `n_mcmc` parameter vectors refilled every `p_mcmc` policy iterations, and the
motion balancer. Pure numpy/torch: the service puts it behind a socket, tests drive it directly.

Algorithm 1 mapped onto the calls:
    line 3       tick(i) refills the buffer by MCMC when p_mcmc iterations passed since the last refill
    lines 7-9    draw(n): the next n buffer entries (a shuffled pass, reshuffled when used up) + clips
    lines 15-16  report(params, values): pairs (s_b, V(s)) stored until the next tick (buffer D)
    lines 24-26  tick(i) fits Vm and Vbar on the stored pairs, then clears them (line 27)

Clips: a `ClipManager` (`common/motion/clip_manager.py`) draws them by the motion balancer;
`report` (or `report_clips`) adds the training segments' outcomes per clip and each tick
reweights the manager by them (adaptive clip sampling, `sampler/clip_outcomes.py`; off for
clip_weighting exp with clip_k = 0). With time bins (`time_bin_s` > 0, `sampler/time_bins.py`)
`draw_episodes` also draws each episode's start time in its clip, through the same manager,
weighted by where the reported failures fell. `sampler/clip_metrics.py` turns the draws and
outcomes into per-class and per-clip metrics.

Shape and class together (`shape_by_class`, issue 55 item 2): Vm is fitted over (s_b, c), c the
class of each pair's clip (its label cut to `class_depth` levels), and each class keeps its own
buffer of `n_mcmc` shapes drawn from exp(-k Vm(s_b, c) / Vbar_c) at each refill. A draw still
takes its clips from the balancer, so the classes are drawn as the class tree (and adaptive clip
sampling) says; each episode's shape is the next one of its class's buffer (a shuffled pass per
class). Sampling each class's conditional rather than the joint density over (s_b, c) keeps
every class in play at the balancer's share, and Vbar_c makes each class's density as sharp
relative to its own returns, so a class the policy tracks well still spreads its shapes by
which of them are hard. `buffer` then holds the classes' buffers one after the other (class c in
rows c n_mcmc .. (c + 1) n_mcmc - 1) and `_order` their draw orders side by side.

A tick is idempotent for a repeated iteration number (a client's retry after a lost reply): the
pairs are already consumed and the refill is keyed on the iteration, not on the tick count.
"""

from __future__ import annotations

import json
import time
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from common import device as devices
from common.params import ParamError, ParamSpace
from common.wire import MAX_KEY
from common.motion.balancer import MotionBalancer
from common.motion.clip_manager import ClipManager
from sampler.clip_metrics import ClipMetrics, clip_class
from sampler.clip_outcomes import ClipOutcomes
from sampler.config import SamplerConfig
from sampler.marginal_value import MarginalValue
from sampler.mcmc import metropolis_hastings
from sampler.time_bins import END_MARGIN_S, TimeBins

STATE_VERSION = 2
"""2: Vm over (shape, class) and per-class buffers (`shape_by_class`); version 1 states still load."""
READABLE_VERSIONS = (1, 2)


class ShapeSampler:
    """Adaptive sampler of task/shape parameters and motion clips; see the module docstring."""

    def __init__(self, config: SamplerConfig, space: ParamSpace,
                 clips: Sequence[tuple[str, str]] | None = None, durations: Mapping[str, float] | None = None):
        """`clips`: (clip id, label) pairs to draw; `durations`: {clip id: length in s} of each,
        needed for start times (`config.time_bin_s` > 0; `common.tasks.registry.task_clip_durations`)."""
        self.config = config
        self.space = space
        self.rng = np.random.default_rng(config.seed)
        self.class_names: tuple[str, ...] = ()
        """The motion classes of `shape_by_class` (sorted), or empty: one buffer over shapes alone."""
        self.class_of_clip: dict[str, int] = {}
        """Clip id -> index in `class_names` (`shape_by_class`)."""
        if config.shape_by_class:
            if not clips:
                raise ValueError("--sampler.shape-by-class draws a shape per motion class: it needs a task with "
                                 "clips (the executor); this task has none")
            labels = {cid: clip_class(label, config.class_depth) for cid, label in clips}
            self.class_names = tuple(sorted(set(labels.values())))
            self.class_of_clip = {cid: self.class_names.index(c) for cid, c in labels.items()}
        self.vm = MarginalValue(space.low_array, space.high_array, config.vm_hidden, config.vm_lr,
                                config.vbar_rate, config.seed, config.probe_points, devices.resolve(config.device),
                                classes=self.class_names)
        self.time_bins: TimeBins | None = None
        """Failure-weighted start times (None: time bins off, or no clips)."""
        if clips and config.time_bin_s > 0:
            missing = [c for c, _ in clips if c not in (durations or {})]
            if missing:
                raise ValueError(f"--sampler.time-bin-s {config.time_bin_s:g} needs every clip's length; none for "
                                 f"{missing[:3]} ({len(missing)} clips): time bins work with the executor's clips only")
            lengths = {c: float(durations[c]) for c, _ in clips}
            self.time_bins = TimeBins(lengths, config.time_bin_s, config.time_kernel, config.time_lambda,
                                      config.time_uniform, config.clip_memory)
        known = {c: float(d) for c, d in (durations or {}).items()}
        self.clips = ClipManager(clips, duration_s=known.__getitem__ if known else None) if clips else None
        """The episodes' clip draws (None: the task uses no clips)."""
        self.clip_outcomes = (ClipOutcomes(self.clips.clip_ids, config.clip_k, config.clip_memory,
                                           config.clip_weighting, config.clip_floor)
                              if self.clips else None)
        self.clip_metrics = ClipMetrics(clips, config.clip_memory) if clips else None
        self.refused_last: list[str] = []
        """Why the last report's refused failure times were refused (one line each)."""
        self._pending_params: list[np.ndarray] = []
        self._pending_values: list[np.ndarray] = []
        self._pending_classes: list[np.ndarray] = []
        """Class index of each pending pair (`shape_by_class`; zeros otherwise), beside `_pending_values`."""
        self.pairs_taken = 0
        """(params, V) pairs `report` stored, over the sampler's life (kept in its state): the
        learner compares it with what it delivered to count pairs a restart lost."""
        self.pairs_trimmed = 0
        """Stored pairs dropped unfitted because more than `max_pending_pairs` waited for a tick."""
        self.generation = 0
        self.last_tick = -1
        self.last_refill_iteration = 0
        self.draws_served = 0
        self.acceptance = 1.0
        self.refill_s = 0.0
        self.fit_s = 0.0
        n_classes = len(self.class_names)
        self.class_acceptance = np.ones(n_classes)
        """Per class: the last refill's MH acceptance rate (`shape_by_class`)."""
        self._class_cursor = np.zeros(n_classes, dtype=np.int64)
        """Per class: draws taken from its pass through its buffer (`shape_by_class`)."""
        self.buffer = space.uniform(self.rng, config.n_mcmc * max(1, n_classes))
        if n_classes:
            self._order = self._class_orders()
            self._cursor = len(self.buffer)
        else:
            self._order = self.rng.permutation(config.n_mcmc)
            self._cursor = 0

    @property
    def per_class(self) -> int:
        """Rows of each class's buffer (`shape_by_class`)."""
        return len(self.buffer) // max(1, len(self.class_names))

    def _class_orders(self) -> np.ndarray:
        """A fresh shuffled pass through every class's rows, side by side (`_order` over classes)."""
        n = self.per_class
        self._class_cursor[:] = 0
        return np.concatenate([c * n + self.rng.permutation(n) for c in range(len(self.class_names))])

    def _class_rows(self, classes: np.ndarray) -> np.ndarray:
        """Buffer rows for draws of these class indices: for each class, the next rows of its pass
        (reshuffled when used up)."""
        n = self.per_class
        rows = np.empty(len(classes), dtype=np.int64)
        for c in np.unique(classes):
            at = np.flatnonzero(classes == c)
            got = 0
            while got < len(at):
                if self._class_cursor[c] == n:
                    self._order[c * n:(c + 1) * n] = c * n + self.rng.permutation(n)
                    self._class_cursor[c] = 0
                take = min(len(at) - got, n - int(self._class_cursor[c]))
                start = c * n + int(self._class_cursor[c])
                rows[at[got:got + take]] = self._order[start:start + take]
                self._class_cursor[c] += take
                got += take
        return rows

    @property
    def balancer(self) -> MotionBalancer | None:
        """The clip manager's motion balancer: its class-tree `probabilities` and the reweighted
        `draw_probabilities` the draws use."""
        return self.clips.balancer if self.clips is not None else None

    def draw(self, n: int) -> tuple[np.ndarray, list[str]]:
        """`n` episode draws: parameters `[n, d]` float64 from the buffer, and `n` clip ids
        (an empty list when the sampler has no clips). Raises ValueError for a bad `n`."""
        if not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= self.config.max_draw:
            raise ValueError(f"draw of n = {n!r}; allowed: an integer in [1, {self.config.max_draw}]")
        if self.class_names:  # the balancer picks the clips, hence the classes; each class's buffer the shapes
            clips = self.clips.draw_clips(self.rng, n)
            rows = self._class_rows(np.array([self.class_of_clip[c] for c in clips], dtype=np.int64))
            self.clip_metrics.count(clips)
            self.draws_served += n
            return self.buffer[rows].copy(), clips
        rows = np.empty(n, dtype=np.int64)
        filled = 0
        while filled < n:
            if self._cursor == len(self._order):
                self._order = self.rng.permutation(len(self.buffer))
                self._cursor = 0
            take = min(n - filled, len(self._order) - self._cursor)
            rows[filled:filled + take] = self._order[self._cursor:self._cursor + take]
            self._cursor += take
            filled += take
        clips = self.clips.draw_clips(self.rng, n) if self.clips else []
        if self.clip_metrics is not None:
            self.clip_metrics.count(clips)
        self.draws_served += n
        return self.buffer[rows].copy(), clips

    def draw_starts(self, clip_ids: Sequence[str]) -> list[float]:
        """A start time (s) in each of these clips, from its failure-weighted time bins through
        the clip manager; empty (no random numbers drawn) when time bins are off: the
        environment then draws a uniform start itself."""
        tb = self.time_bins
        if tb is None:
            return []
        return [self.clips.draw_start(self.rng, c, END_MARGIN_S, tb.weights(c), tb.bin_s) for c in clip_ids]

    def draw_episodes(self, n: int) -> tuple[np.ndarray, list[str], list[float]]:
        """`draw(n)` and `draw_starts` of its clips: what a draw request is answered with."""
        params, clips = self.draw(n)
        return params, clips, self.draw_starts(clips)

    def report(self, params: np.ndarray, values: np.ndarray,
               clips: tuple[Sequence[str], Sequence[int], Sequence[int]] = ((), (), ()),
               failures: tuple[Sequence[str], Sequence[float]] = ((), ()),
               pair_clips: Sequence[str] = ()) -> int:
        """Store pairs (s_b `[m, d]`, V(s) `[m]`) for the next fit, `clips`, the training
        segments per clip (ids, segments, tracked; `report_clips`), `failures`, the clip and
        clip time (s) of each failed segment (`report_failures`), and `pair_clips`, the clip of
        each pair's episode (`shape_by_class`: one per pair, required; off: none); returns m.

        Raises `ParamError` (a ValueError) naming the first out-of-range or NaN entry or a clip
        of a pair this sampler does not draw, or a ValueError for the clip counts; everything is
        checked before anything is stored. A bad failure time is refused alone (`refused_last`
        says why) and the rest is stored."""
        clip_rows = self._clip_rows(*clips)
        fail_rows, refusals = self._fail_rows(*failures)
        params = np.asarray(params, dtype=np.float64)
        values = np.asarray(values, dtype=np.float64)
        if params.ndim != 2 or params.shape[1] != self.space.dim:
            raise ParamError(f"params of shape {params.shape}; expected [m, {self.space.dim}] "
                             f"for {list(self.space.names)}")
        if values.shape != (params.shape[0],):
            raise ParamError(f"values of shape {values.shape}; expected [{params.shape[0]}], one per params row")
        if not np.isfinite(values).all():
            row = int(np.flatnonzero(~np.isfinite(values))[0])
            raise ParamError(f"values[{row}] = {values[row]}; values must be finite returns")
        params = self.space.validate_batch(params)  # float32 rounding at a bound is accepted and clipped
        pair_classes = self._pair_classes(pair_clips, params.shape[0])
        self._pending_params.append(params.copy())
        self._pending_values.append(values.copy())
        self._pending_classes.append(pair_classes)
        self.pairs_taken += params.shape[0]
        self._trim_pending()
        if self.clip_outcomes is not None:
            self.clip_outcomes.add(clip_rows)
        self._add_failures(fail_rows, refusals)
        return params.shape[0]

    def _pair_classes(self, pair_clips: Sequence[str], m: int) -> np.ndarray:
        """The class index of each pair's clip (`[m]` zeros when classes are off); ParamError for
        clips sent to a sampler without classes, a count other than one per pair, or a clip this
        sampler does not draw."""
        if not self.class_names:
            if len(pair_clips):
                raise ParamError(f"{len(pair_clips)} pair clip ids: this sampler fits Vm over shapes alone "
                                 "(--sampler.shape-by-class off); send none")
            return np.zeros(max(m, 0), dtype=np.int64)
        if len(pair_clips) != m:
            raise ParamError(f"{len(pair_clips)} pair clip ids for {m} pairs: this sampler fits Vm over (shape, "
                             "class) (--sampler.shape-by-class); send the clip of each pair's episode")
        out = np.empty(m, dtype=np.int64)
        for i, cid in enumerate(pair_clips):
            c = self.class_of_clip.get(cid) if isinstance(cid, str) else None
            if c is None:
                raise ParamError(f"pair_clips[{i}] = {str(cid)[:64]!r} is not a clip this sampler draws "
                                 f"({len(self.class_of_clip)} clips in {len(self.class_names)} classes)")
            out[i] = c
        return out

    def _clip_rows(self, clip_ids: Sequence[str], segments: Sequence[int], tracked: Sequence[int]) -> list[tuple[int, int, int]]:
        """`ClipOutcomes.check` of these counts; a sampler without clips takes none."""
        if self.clip_outcomes is None:
            if len(clip_ids):
                raise ValueError(f"clip outcomes for {list(clip_ids)[:3]}: this sampler draws no clips")
            return []
        return self.clip_outcomes.check(clip_ids, segments, tracked)

    def _fail_rows(self, clip_ids: Sequence[str], times: Sequence[float]) -> tuple[list[int], list[str]]:
        """`TimeBins.check` of these failure times; a sampler without time bins takes none."""
        if self.time_bins is None:
            if len(clip_ids) or len(times):
                raise ValueError(f"{max(len(clip_ids), len(times))} failure times: this sampler keeps no time bins "
                                 "(--sampler.time-bin-s 0); send none")
            return [], []
        return self.time_bins.check(clip_ids, times)

    def _add_failures(self, rows: list[int], refusals: list[str]) -> int:
        self.refused_last = list(refusals)
        return self.time_bins.add(rows, refusals) if self.time_bins is not None else 0

    def report_failures(self, clip_ids: Sequence[str], times: Sequence[float]) -> int:
        """The clip and clip time (s) of failed training segments, for the next tick's start
        weights; returns how many were counted. Each bad entry is refused alone (`refused_last`);
        ValueError only for lists of different lengths, or for any entry when time bins are off."""
        return self._add_failures(*self._fail_rows(clip_ids, times))

    def report_clips(self, clip_ids: Sequence[str], segments: Sequence[int], tracked: Sequence[int]) -> int:
        """Training segments per clip and how many were tracked to the clip's end, for the next
        tick's reweighting; returns the segments added. ValueError naming a clip this sampler does
        not draw or counts that do not add up (nothing stored); a sampler without clips takes none."""
        rows = self._clip_rows(clip_ids, segments, tracked)
        return self.clip_outcomes.add(rows) if self.clip_outcomes is not None else 0

    def _trim_pending(self) -> None:
        """Keep only the newest `max_pending_pairs` pairs (bounded memory if ticks stop coming)."""
        total = sum(len(v) for v in self._pending_values)
        while total > self.config.max_pending_pairs and self._pending_values:
            excess = total - self.config.max_pending_pairs
            self.pairs_trimmed += min(excess, len(self._pending_values[0]))
            if len(self._pending_values[0]) <= excess:
                total -= len(self._pending_values.pop(0))
                self._pending_params.pop(0)
                self._pending_classes.pop(0)
            else:
                self._pending_values[0] = self._pending_values[0][excess:]
                self._pending_params[0] = self._pending_params[0][excess:]
                self._pending_classes[0] = self._pending_classes[0][excess:]
                total -= excess

    @property
    def pending_pairs(self) -> int:
        return sum(len(v) for v in self._pending_values)

    def tick(self, iteration: int) -> dict[str, float]:
        """One policy iteration finished: fit Vm on the stored pairs, refill the buffer when
        `p_mcmc` iterations passed since the last refill, and return `stats()`."""
        if self._pending_values:
            t0 = time.perf_counter()
            classes = np.concatenate(self._pending_classes) if self.class_names else None
            self.vm.fit(np.concatenate(self._pending_params), np.concatenate(self._pending_values),
                        self.config.vm_fit_steps, self.config.vm_minibatch, self.rng, classes)
            self.fit_s = time.perf_counter() - t0
            self._pending_params.clear()
            self._pending_values.clear()
            self._pending_classes.clear()
        if self.clip_outcomes is not None:
            self.clip_outcomes.update()
            if self.clip_outcomes.active:
                self.clips.reweight(self.clip_outcomes.factors())
            self.clip_metrics.update()
        if self.time_bins is not None:
            self.time_bins.update()
        if iteration < self.last_refill_iteration:  # the learner went back (resumed without our state)
            self.last_refill_iteration = iteration
        if iteration - self.last_refill_iteration >= self.config.p_mcmc:
            self.refill()
            self.last_refill_iteration = iteration
        self.last_tick = max(self.last_tick, iteration)
        return self.stats()

    def refill(self) -> None:
        """Fill the buffer with `n_mcmc` draws from exp(-k Vm / |Vbar|) (Algorithm 1, line 3).

        Until Vm has seen data (and always for k = 0) the draws are uniform over the box.
        Over classes: `n_mcmc` per class from exp(-k Vm(., c) / |Vbar_c|), one MH run each."""
        t0 = time.perf_counter()
        cfg = self.config
        if self.class_names:
            self._refill_classes()
        elif cfg.k == 0 or not self.vm.fitted:
            self.buffer = self.space.uniform(self.rng, cfg.n_mcmc)
            self.acceptance = 1.0
        else:
            result = metropolis_hastings(self.vm, self.space.low_array, self.space.high_array, cfg.k,
                                         self.vm.temperature(cfg.vbar_floor), cfg.n_mcmc, cfg.n_chains,
                                         cfg.burn_in, cfg.thin, self.rng)
            self.buffer = result.samples
            self.acceptance = result.acceptance_rate
        if self.class_names:
            self._order = self._class_orders()
            self._cursor = len(self.buffer)
        else:
            self._order = self.rng.permutation(len(self.buffer))
            self._cursor = 0
        self.generation += 1
        self.refill_s = time.perf_counter() - t0

    def _refill_classes(self) -> None:
        cfg, n_classes = self.config, len(self.class_names)
        if cfg.k == 0 or not self.vm.fitted:
            self.buffer = self.space.uniform(self.rng, cfg.n_mcmc * n_classes)
            self.class_acceptance = np.ones(n_classes)
        else:
            parts = []
            for c in range(n_classes):
                result = metropolis_hastings(lambda x, c=c: self.vm(x, c), self.space.low_array, self.space.high_array,
                                             cfg.k, self.vm.temperature(cfg.vbar_floor, c), cfg.n_mcmc, cfg.n_chains,
                                             cfg.burn_in, cfg.thin, self.rng)
                parts.append(result.samples)
                self.class_acceptance[c] = result.acceptance_rate
            self.buffer = np.concatenate(parts)
        self.acceptance = float(self.class_acceptance.mean())

    def stats(self) -> dict[str, float]:
        """Flat metrics (the learner logs them under `sampler/`):

        buffer/generation, buffer/mean/<param>, buffer/std/<param>   the MCMC buffer
        vm/min, vm/max, vm/mean      Vm over fixed uniform probe points (value units)
        vm/vbar, vm/temperature      the running average and the |Vbar| floor actually used
        vm/fit_loss, vm/fit_s        last fit's MSE (value units^2) and wall time (s)
        vm/pairs_seen, vm/pending_pairs   pairs fitted; stored, waiting for the next tick
        vm/pairs_taken, vm/pairs_trimmed  pairs stored over the sampler's life; dropped unfitted (bound)
        mcmc/acceptance, mcmc/refill_s   last refill's MH acceptance rate and wall time (s)
        draws/served, iteration
        clips/count, clips/p_min, clips/p_max   draw probabilities (when clips are used)
        clips/segments_seen, clips/tracked_pct, clips/rate_min, clips/rate_max
                                     training segments reported, the recent share tracked to the
                                     clip's end (all clips), its lowest and highest clip (r_c)
        clips/class/<class>/starts_pct, .../success_pct, clips/clip/<id>/..., clips/success_pct/*
                                     each class's and clip's share of starts and of segments
                                     tracked (`sampler/clip_metrics.py`)
        clips/time/fails_seen, refused, entropy, top_share   the time bins (`sampler/time_bins.py`)
        vm/class/<class>/min, max, vbar, acceptance    over (shape, class) (`shape_by_class`): Vm(., c)
                                     over the class's buffer, Vbar_c, its last refill's MH acceptance
        vm/lowest/<class>, vm/lowest_vbar    the class of lowest Vbar_c (a point at each tick it is the
                                     lowest, as the worst clips are named) and that Vbar_c
        """
        out: dict[str, float] = {"iteration": float(self.last_tick), "buffer/generation": float(self.generation)}
        mean, std = self.buffer.mean(axis=0), self.buffer.std(axis=0)
        for i, name in enumerate(self.space.names):
            out[f"buffer/mean/{name}"] = float(mean[i])
            out[f"buffer/std/{name}"] = float(std[i])
        probe_vm = self.vm.probe_values()
        out.update({
            "vm/min": float(probe_vm.min()), "vm/max": float(probe_vm.max()), "vm/mean": float(probe_vm.mean()),
            "vm/vbar": self.vm.vbar, "vm/temperature": self.vm.temperature(self.config.vbar_floor),
            "vm/fit_loss": self.vm.last_loss, "vm/fit_s": self.fit_s,
            "vm/pairs_seen": float(self.vm.pairs_seen), "vm/pending_pairs": float(self.pending_pairs),
            "vm/pairs_taken": float(self.pairs_taken), "vm/pairs_trimmed": float(self.pairs_trimmed),
            "mcmc/acceptance": self.acceptance, "mcmc/refill_s": self.refill_s,
            "draws/served": float(self.draws_served),
        })
        if self.clips is not None:
            p = self.clips.draw_probabilities
            out.update({"clips/count": float(len(p)), "clips/p_min": float(p.min()), "clips/p_max": float(p.max())})
            out.update(self.clip_outcomes.stats())
            out.update(self.clip_metrics.stats(self.clip_outcomes.segments, self.clip_outcomes.tracked))
        if self.time_bins is not None:
            out.update(self.time_bins.stats())
        if self.class_names:
            out.update(self.class_stats())
        return out

    def class_stats(self) -> dict[str, float]:
        """The per-class part of `stats()` (`shape_by_class`)."""
        n, out = self.per_class, {}
        buffer_vm = self.vm(self.buffer, np.repeat(np.arange(len(self.class_names)), n)).reshape(-1, n)
        for c, name in enumerate(self.class_names):
            out[f"vm/class/{name}/min"] = float(buffer_vm[c].min())
            out[f"vm/class/{name}/max"] = float(buffer_vm[c].max())
            out[f"vm/class/{name}/vbar"] = float(self.vm.vbar_c[c])
            out[f"vm/class/{name}/acceptance"] = float(self.class_acceptance[c])
        lowest = int(np.argmin(self.vm.vbar_c))
        out[f"vm/lowest/{self.class_names[lowest]}"] = float(self.vm.vbar_c[lowest])
        out["vm/lowest_vbar"] = float(self.vm.vbar_c[lowest])
        # NOTE: a key past the wire's limit (with the learner's "sampler/") would make the whole
        # stats reply undecodable; a class that deep keeps only what fits (the clip metrics' rule).
        return {k: v for k, v in out.items() if len(k) + len("sampler/") <= MAX_KEY}

    def state_dict(self) -> dict[str, Any]:
        """`{"meta": primitives, "arrays": numpy arrays}`: everything needed to continue exactly
        (buffer, draw order, pending pairs, RNG, Vm with Adam's moments). It is what `StateMsg`
        carries; for a `torch.load(weights_only=True)` checkpoint convert with `state_to_torch`."""
        vm_meta, vm_arrays = self.vm.state()
        meta = {
            "version": STATE_VERSION, "names": list(self.space.names), "generation": self.generation,
            "last_tick": self.last_tick, "last_refill_iteration": self.last_refill_iteration,
            "draws_served": self.draws_served, "acceptance": self.acceptance, "refill_s": self.refill_s,
            "fit_s": self.fit_s, "cursor": self._cursor, "rng": json.dumps(self.rng.bit_generator.state),
            "pairs_taken": self.pairs_taken, "pairs_trimmed": self.pairs_trimmed,
            "vm": vm_meta, "classes": list(self.class_names), "class_cursors": self._class_cursor.tolist(),
            "class_acceptance": self.class_acceptance.tolist(),
        }
        pending_p = np.concatenate(self._pending_params) if self._pending_params else np.zeros((0, self.space.dim))
        pending_v = np.concatenate(self._pending_values) if self._pending_values else np.zeros(0)
        arrays = {"buffer": self.buffer.copy(), "order": self._order.astype(np.int64),
                  "pending_params": pending_p, "pending_values": pending_v}
        if self.class_names:
            arrays["pending_classes"] = (np.concatenate(self._pending_classes) if self._pending_classes
                                         else np.zeros(0, dtype=np.int64)).astype(np.int64)
        arrays.update({f"vm/{k}": v for k, v in vm_arrays.items()})
        if self.clip_outcomes is not None:
            meta["clips"], clip_arrays = self.clip_outcomes.state()
            arrays.update(clip_arrays)
            meta["clip_metrics"], metric_arrays = self.clip_metrics.state()
            arrays.update(metric_arrays)
        if self.time_bins is not None:
            meta["time_bins"], time_arrays = self.time_bins.state()
            arrays.update(time_arrays)
        return {"meta": meta, "arrays": arrays}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a `state_dict()`; raises ValueError if it belongs to another parameter space."""
        meta, arrays = state["meta"], {k: np.array(v) for k, v in state["arrays"].items()}
        if meta.get("version") not in READABLE_VERSIONS:
            raise ValueError(f"sampler state version {meta.get('version')!r}; this code reads {list(READABLE_VERSIONS)}")
        if list(meta["names"]) != list(self.space.names):
            raise ValueError(f"sampler state is for parameters {meta['names']}, "
                             f"this sampler has {list(self.space.names)}")
        box_changed = self.vm.load_state(meta["vm"], {k[3:]: v for k, v in arrays.items() if k.startswith("vm/")})
        # NOTE: a run may resume on another box (a curriculum stage, `--task.body.shape-box-scale`):
        # Vm keeps its values (re-expressed for the new box) and pending shapes are moved into the
        # new box; the buffer is refilled at once below, since the old one covers only the old box.
        box = lambda a: np.clip(a.astype(np.float64).reshape(-1, self.space.dim), self.space.low_array, self.space.high_array)  # noqa: E731
        self.buffer = box(arrays["buffer"])
        self._order = arrays["order"].astype(np.int64)
        pending_v = arrays["pending_values"].astype(np.float64).reshape(-1)
        pending_p = box(arrays["pending_params"])
        saved_classes = [str(c) for c in meta.get("classes", [])]  # a version 1 state: none
        classes_changed = saved_classes != list(self.class_names)
        pending_c, unplaced = self._restored_pending_classes(saved_classes, arrays, len(pending_v))
        keep = pending_c >= 0
        self._pending_params = [pending_p[keep]] if keep.any() else []
        self._pending_values = [pending_v[keep]] if keep.any() else []
        self._pending_classes = [pending_c[keep]] if keep.any() else []
        self._cursor = int(meta["cursor"])
        if self.class_names and not classes_changed:
            self._class_cursor = np.array(meta["class_cursors"], dtype=np.int64).reshape(len(self.class_names))
            self.class_acceptance = np.array(meta["class_acceptance"], dtype=np.float64).reshape(len(self.class_names))
        else:
            self._class_cursor = np.zeros(len(self.class_names), dtype=np.int64)
            self.class_acceptance = np.ones(len(self.class_names))
        self.generation, self.last_tick = int(meta["generation"]), int(meta["last_tick"])
        self.last_refill_iteration = int(meta["last_refill_iteration"])
        self.draws_served = int(meta["draws_served"])
        self.acceptance, self.refill_s = float(meta["acceptance"]), float(meta["refill_s"])
        self.fit_s = float(meta["fit_s"])
        # NOTE: a state from before these counts: every pair it fitted or holds was taken.
        self.pairs_taken = int(meta.get("pairs_taken", self.vm.pairs_seen + len(pending_v)))
        self.pairs_trimmed = int(meta.get("pairs_trimmed", 0)) + unplaced
        self.rng = np.random.default_rng()
        self.rng.bit_generator.state = json.loads(meta["rng"])
        if self.clip_outcomes is not None:  # a state from before adaptive clip sampling has none: every clip unseen
            self.clip_outcomes.load_state(meta.get("clips"), arrays)
            if self.clip_outcomes.active:
                self.clips.reweight(self.clip_outcomes.factors())
            self.clip_metrics.load_state(meta.get("clip_metrics"), arrays)
        if self.time_bins is not None:  # a state without time bins: every clip starts without failures
            self.time_bins.load_state(meta.get("time_bins"), arrays)
        if box_changed or classes_changed:
            # NOTE: a state over other classes (shape_by_class switched, or another library) has
            # buffers that do not match this sampler's classes: refill them from the remapped Vm.
            self.refill()
            self.last_refill_iteration = self.last_tick

    def _restored_pending_classes(self, saved: list[str], arrays: Mapping[str, np.ndarray],
                                  m: int) -> tuple[np.ndarray, int]:
        """This sampler's class index of each restored pending pair (-1: none, the pair is dropped)
        and how many were dropped: pairs of a class it lacks, or without a class (a state over
        shapes alone) when it fits over classes."""
        if not self.class_names:
            return np.zeros(m, dtype=np.int64), 0
        if not saved:
            return np.full(m, -1, dtype=np.int64), m
        idx = np.asarray(arrays["pending_classes"]).astype(np.int64).reshape(-1)
        if len(idx) != m or (m and (idx.min() < 0 or idx.max() >= len(saved))):
            raise ValueError(f"sampler state pending_classes: {len(idx)} entries for {m} pending pairs; "
                             f"expected one per pair, each in [0, {len(saved)})")
        mapping = np.array([self.class_names.index(c) if c in self.class_names else -1 for c in saved], dtype=np.int64)
        out = mapping[idx]
        return out, int((out < 0).sum())


def state_to_torch(state: dict[str, Any]) -> dict[str, Any]:
    """A sampler state with its arrays as torch tensors: loadable by `torch.load(weights_only=True)`
    (which refuses numpy arrays). The inverse is `state_from_torch`."""
    return {"meta": state["meta"], "arrays": {k: torch.from_numpy(np.array(v)) for k, v in state["arrays"].items()}}


def state_from_torch(state: dict[str, Any]) -> dict[str, Any]:
    """Undo `state_to_torch`: tensors back to numpy arrays (what `load_state_dict`/`StateMsg` take)."""
    return {"meta": state["meta"], "arrays": {k: np.asarray(v.numpy() if hasattr(v, "numpy") else v)
                                              for k, v in state["arrays"].items()}}
