"""`Learner`: the networks, the PPO optimizer and the run's counters; turns unrolls into a
`Batch`, updates, and produces the `WeightsMsg` actors run. No sockets, no Ray: data-parallel
replicas (`learner.replicas`) are handed in as an object that starts and finishes their share
of each update."""

from __future__ import annotations

import collections
import json
from typing import Any

import numpy as np
import torch

from common import wire
from common.policy import GaussianPolicy, ValueNet, anneal_log_std, policy_tensors
from common.tasks.registry import make_env
from common import device as devices
from learner.config import RunConfig
from learner.data_parallel import GradientSync
from learner.ppo import PPO, Batch

MAX_CLIPS_COUNTED = 65536
"""Distinct clip ids the learner counts segments of between two sampler reports (a bound on
memory; the sampler draws far fewer)."""


class Learner:
    def __init__(self, cfg: RunConfig):
        self.cfg = cfg
        self.device = devices.resolve(cfg.learner.device)
        torch.manual_seed(cfg.seed)
        env = make_env(cfg.task, seed=cfg.seed)
        self.obs_dim, self.act_dim, self.space = env.obs_dim, env.act_dim, env.space
        self.policy = GaussianPolicy(self.obs_dim, self.act_dim, cfg.policy).to(self.device)
        self.value = ValueNet(self.obs_dim, cfg.policy).to(self.device)
        self.ppo = PPO(self.policy, self.value, cfg.ppo)
        self.sync: GradientSync | None = None
        """This process's place in the data-parallel group, once `learner.replicas` has formed it."""
        self.replicas = None
        """On rank 0 of a data-parallel group: the `learner.replicas.ReplicaGroup` that runs the
        other replicas' share of each update."""
        self.generator = torch.Generator().manual_seed(cfg.seed)
        self.rng = np.random.default_rng(cfg.seed)
        self.iteration = 0
        self.env_steps = 0
        self.policy_version = 0
        self.episodes = 0
        self.train_seconds = 0.0
        """Wall seconds spent training, summed over every session of a resumed run (checkpointed)."""
        self.recent_returns: collections.deque[float] = collections.deque(maxlen=100)
        self.recent_lengths: collections.deque[int] = collections.deque(maxlen=100)
        self.counters: collections.Counter[str] = collections.Counter()
        self.clip_segments: dict[str, list[int]] = {}
        """Clip id -> [segments, tracked] since the last `take_clip_segments`."""
        self.clip_failures: list[tuple[str, float]] = []
        """(clip id, clip time in s) of each failed segment since the last `take_clip_failures`,
        the first `wire.MAX_FAILURE_TIMES` of them."""

    def weights_msg(self) -> wire.WeightsMsg:
        return wire.WeightsMsg(policy_version=self.policy_version, tensors=policy_tensors(self.policy))

    @staticmethod
    def batch_from(unrolls: list[wire.UnrollMsg]) -> Batch:
        """Concatenate `[T, N]` unrolls along the environment axis into one `[T, B]` CPU batch."""
        cat = lambda name, dtype: torch.as_tensor(  # noqa: E731
            np.concatenate([getattr(u, name) for u in unrolls], axis=1).astype(dtype, copy=False)
        )
        return Batch(
            obs=cat("obs", np.float32),
            next_obs=cat("next_obs", np.float32),
            actions=cat("actions", np.float32),
            logp=cat("logp", np.float32),
            rewards=cat("rewards", np.float32),
            terminated=cat("terminated", np.bool_),
            truncated=cat("truncated", np.bool_),
        )

    def record_episodes(self, unrolls: list[wire.UnrollMsg]) -> None:
        for u in unrolls:
            self.recent_returns.extend(u.episode_returns)
            self.recent_lengths.extend(u.episode_lengths)
            self.episodes += len(u.episode_returns)
            self.counters["divergences"] += u.divergences
            times = u.segment_times if len(u.segment_times) == len(u.segment_clips) else [None] * len(u.segment_clips)
            for clip, tracked, at in zip(u.segment_clips, u.segment_tracked, times):
                if not tracked and at is not None and len(self.clip_failures) < wire.MAX_FAILURE_TIMES:
                    self.clip_failures.append((clip, float(at)))
                if clip not in self.clip_segments and len(self.clip_segments) >= MAX_CLIPS_COUNTED:
                    continue
                counts = self.clip_segments.setdefault(clip, [0, 0])
                counts[0] += 1
                counts[1] += int(tracked)

    def take_clip_segments(self) -> tuple[list[str], list[int], list[int]]:
        """Clip segments recorded since the last call, per clip: (ids, segments, tracked), for the
        sampler's adaptive clip sampling (`sampler/clip_outcomes.py`)."""
        ids = sorted(self.clip_segments)
        out = ids, [self.clip_segments[c][0] for c in ids], [self.clip_segments[c][1] for c in ids]
        self.clip_segments = {}
        return out

    def take_clip_failures(self) -> tuple[list[str], list[float]]:
        """The failed segments recorded since the last call: (clip ids, clip times in s where each
        failed), for the sampler's time bins (`sampler/time_bins.py`). NOTE: past
        `wire.MAX_FAILURE_TIMES` in one iteration the later ones are dropped; an iteration of
        8192 steps ends far fewer episodes."""
        out = [c for c, _ in self.clip_failures], [t for _, t in self.clip_failures]
        self.clip_failures = []
        return out

    def value_pairs(self, unrolls: list[wire.UnrollMsg], n: int) -> tuple[np.ndarray, np.ndarray]:
        """`n` random `(task parameters, V(s))` pairs from these unrolls, for the sampler's
        marginal value fit (Won & Lee 2019, Algorithm 1)."""
        params, values, _ = self.value_triples(unrolls, n)
        return params, values

    def value_triples(self, unrolls: list[wire.UnrollMsg], n: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """`value_pairs` and the clip each pair's episode was drawn with (`UnrollMsg.step_clips`;
        "" for a step without one), for a sampler that fits Vm over (shape, class)."""
        obs = np.concatenate([u.obs.reshape(-1, self.obs_dim) for u in unrolls])
        params = np.concatenate([u.params.reshape(-1, u.params.shape[-1]) for u in unrolls])
        names: list[str] = []
        steps = []
        for u in unrolls:  # every unroll's step clips as indices into one list of names ("" last: none)
            offset = len(names)
            names += list(u.clip_names)
            if u.step_clips.size:
                steps.append(np.where(u.step_clips >= 0, u.step_clips.astype(np.int64) + offset, -1).reshape(-1))
            else:
                steps.append(np.full(u.rewards.size, -1, np.int64))
        step_clips = np.concatenate(steps)
        names.append("")
        idx = self.rng.choice(len(obs), size=min(n, len(obs)), replace=False)
        values = self.ppo.values_of(torch.as_tensor(obs[idx], device=self.device)).cpu().numpy()
        return params[idx].astype(np.float32), values.astype(np.float32), [names[i] for i in step_clips[idx]]

    def apply_update(self, batch: Batch, env_steps: int) -> dict[str, float]:
        """The PPO update on a CPU batch at `env_steps` into the run (learning-rate schedule and
        variance controller first): what every data-parallel replica runs on the same batch."""
        self.ppo.set_progress(env_steps / self.cfg.total_env_steps)
        anneal_log_std(self.policy, self.cfg.policy, env_steps)
        metrics = self.ppo.update(batch.to(self.device), self.generator, self.sync)
        if self.sync is not None:
            self.sync.check_equal([*self.policy.state_dict().values(), *self.value.state_dict().values()])
        return metrics

    def update(self, unrolls: list[wire.UnrollMsg]) -> dict[str, float]:
        batch = self.batch_from(unrolls)
        others = self.replicas.start_update(batch, self.env_steps) if self.replicas is not None else None
        try:
            metrics = self.apply_update(batch, self.env_steps)
        except Exception:
            if others is not None:  # a replica that failed first is the cause: raise its error instead
                self.replicas.finish_update(others, timeout_s=5.0)
            raise
        if others is not None:
            self.replicas.finish_update(others)
        steps = int(batch.rewards.numel())
        self.env_steps += steps
        self.iteration += 1
        self.policy_version += 1
        self.record_episodes(unrolls)
        out = {f"losses/{k}": v for k, v in metrics.items()}
        out["charts/batch_reward"] = float(batch.rewards.mean())
        if self.recent_returns:
            out["charts/episode_return"] = float(np.mean(self.recent_returns))
            out["charts/episode_length"] = float(np.mean(self.recent_lengths))
        out["charts/episodes"] = float(self.episodes)
        out["stats/obs_normalizer_limited"] = float(self.policy.normalizer.limited_updates)
        return out

    def state_dict(self) -> dict[str, Any]:
        """Everything a resume needs. ValueError (nothing returned, so no checkpoint written) if
        the observation normalizer holds a statistic no bounded update can produce."""
        self.policy.normalizer.check()
        return {
            "config": self.cfg.to_json(),
            "iteration": self.iteration,
            "env_steps": self.env_steps,
            "policy_version": self.policy_version,
            "episodes": self.episodes,
            "train_seconds": self.train_seconds,
            "policy": self.policy.state_dict(),
            "value": self.value.state_dict(),
            "optimizer": self.ppo.optimizer.state_dict(),
            "lr": self.ppo.lr,
            "counters": dict(self.counters),
            "recent_returns": list(self.recent_returns),
            "recent_lengths": list(self.recent_lengths),
            "torch_rng": torch.get_rng_state(),
            "generator": self.generator.get_state(),
            "numpy_rng": json.dumps(self.rng.bit_generator.state),  # picks the sampler's value pairs
        }

    def load_networks(self, state: dict[str, Any]) -> None:
        """A checkpoint's policy (with its observation statistics) and value function: what a
        resume and a fine-tune (`learner.fine_tune`) both take."""
        self.policy.load_state_dict(state["policy"])
        # NOTE: checkpoints from before the value net's return statistics have none; (0, 1) is
        # what their value net computed, and the first update's output-preserving rescale starts there.
        self.value.load_state_dict({**{k: v for k, v in self.value.state_dict().items() if k.startswith("target_")},
                                    **state["value"]})

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.load_networks(state)
        self.ppo.optimizer.load_state_dict(state["optimizer"])
        self.ppo.restore_lr(float(state["lr"]))
        self.iteration = int(state["iteration"])
        self.env_steps = int(state["env_steps"])
        self.policy_version = int(state["policy_version"])
        self.episodes = int(state["episodes"])
        # NOTE: checkpoints before train_seconds existed resume with the time unknown (NaN).
        self.train_seconds = float(state.get("train_seconds", float("nan")))
        self.counters = collections.Counter(state["counters"])
        self.recent_returns.extend(state["recent_returns"])
        self.recent_lengths.extend(state["recent_lengths"])
        torch.set_rng_state(state["torch_rng"])
        self.generator.set_state(state["generator"])
        if "numpy_rng" in state:  # checkpoints before it was saved resume with a fresh stream
            self.rng.bit_generator.state = json.loads(state["numpy_rng"])
