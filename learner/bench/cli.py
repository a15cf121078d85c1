"""`morphmimic bench <name>`: benchmark scripts, each comparing two things in one run."""

from __future__ import annotations

from learner.cli import dispatch


BENCHMARKS: dict[str, tuple[str, str]] = {
    "throughput": ("learner.bench.throughput", "end-to-end collection vs pure simulation, learner share, transport bytes/s"),
    "learner": ("learner.bench.learner_update", "PPO update per minibatch step: the reference loop vs PPO.update, same data"),
    "characters": ("learner.bench.characters", "build/compile per shape, on-the-fly change, sim cost per control step"),
    "episodes": ("learner.bench.episodes", "per shape task: reset on a new body vs a control step, and the resets' share"),
    "env-steps": ("learner.bench.env_steps", "a control step in this tree vs another git revision, and whether both compute the same"),
    "shape-references": ("learner.bench.shape_references", "executor-shape: a reset's reference retargeted whole vs frames made on demand"),
    "shape-batch": ("learner.bench.shape_batch", "a shape task's step as one batch vs its single environments vs pure physics"),
    "sampler": ("learner.bench.sampler", "MCMC refill time vs a policy iteration, draw latency through the socket"),
    "soak": ("learner.bench.soak", "train under every fault kind, then clean: survived, losses uncounted, return"),
    "curve": ("learner.bench.curve", "the unroll stream and a sampler round trip with CURVE vs plain sockets"),
    "replicas": ("learner.bench.replicas", "one PPO update in one process vs shared by data-parallel replicas, same batch"),
    "scaling": ("learner.bench.scaling", "fresh samples/s and learner share against rollout actors x learner replicas"),
    "capacity": ("learner.bench.capacity", "per-sample costs by network width: simulation, inference, transport, PPO update, all-reduce"),
}


def main(argv: list[str]) -> int:
    return dispatch("morphmimic bench", "benchmark", BENCHMARKS, argv)
