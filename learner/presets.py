"""Named starting configurations for `python -m learner.main --preset NAME`.

Each preset is a complete `RunConfig`; command-line options override its fields.
"""

from __future__ import annotations

from actors.config import ActorConfig
from learner.config import RunConfig
from sampler.config import SamplerConfig

PRESETS: dict[str, tuple[str, RunConfig]] = {
    "reach": (
        "two-link arm reaches sampled targets: the backbone's learnable toy task (~2 min on 2 cores)",
        RunConfig(),
    ),
    "reach-tiny": (
        "a few iterations of reach for smoke tests",
        RunConfig(
            name="reach-tiny",
            total_env_steps=3 * 1024,
            steps_per_iteration=1024,
            checkpoint_every=1,
            actors=ActorConfig(num_actors=2, envs_per_actor=4, unroll_length=32),
            sampler=SamplerConfig(p_mcmc=2, n_mcmc=200, vm_fit_steps=20),
            vm_plot_every=1,
        ),
    ),
}
