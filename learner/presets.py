"""Named starting configurations for `python -m learner.main --preset NAME`.

Each preset is a complete `RunConfig`; command-line options override its fields.
"""

from __future__ import annotations

import dataclasses

from actors.config import ActorConfig
from learner.config import RunConfig
from learner.ppo import PPOConfig
from sampler.config import SamplerConfig

REACH_PPO = PPOConfig(lr_schedule="adaptive", kl_target=0.02, proximal_anchor=True, epochs=5, minibatch=256)
"""The reach task's PPO. Its log-std is learned, and at a constant 3e-4 it shrank (entropy
-3.0) until one update's KL reached 3-11 in the last third of the default run; with the learner
taking 79-90% of wall time, a fifth of the collected steps were dropped as stale. The adaptive
step size (KL target 0.02) holds the KL at 0.02-0.03, the proximal anchor measures it against
the policy the update starts from, and 5 epochs of 256 (a quarter of the gradient steps) keep
the learner up with two actors: no stale drops, learner 60%, mean return over the last third
37.6 against 34.6 before (400k steps; docs/ppo.md has every arm)."""


PRESETS: dict[str, tuple[str, RunConfig]] = {
    "reach": (
        "two-link arm reaches sampled targets: the backbone's learnable toy task (~2 min on 2 cores)",
        RunConfig(ppo=REACH_PPO),
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


ADAPTIVE_K = 1.0
"""Uniformity knob of the shape presets' adaptive sampling (see `_shape_preset`)."""


def _shape_preset(character: str, parameterization: str, plot: tuple[str, str], variant: str = "",
                  swimmer: bool = False) -> RunConfig:
    """Won & Lee 2019 over one character family (METHOD.md A): 30 Hz control, 480 Hz physics
    (the characters' stable default; the paper runs 600 Hz), 30 s episodes, 3 x 128 ReLU nets,
    gamma 0.95, 4096 transitions per update, 10 epochs of 128-transition minibatches, adaptive
    shape sampling with k = 1.

    Choices measured on this 2-core machine: 5 epochs x 256 (a quarter of the gradient steps)
    left the learner idle 95% of the time and learned too slowly per sample (episode length
    28 -> 35 steps in 320k steps), so the paper's 10 x 128 is back; k = 5 (the sampler's
    default) weighted the worst shapes ~400x over the best early on (Vm 15..43, Vbar 23), so
    training chased bodies it could not yet control: k = 1 keeps that ratio near 3. Initial
    action noise is small (log std -1 on actions scaled by 0.5 rad). The quadruped's shanks may
    touch the floor (its shank capsules graze it in the trot on many random shapes: 16 of 16
    zero-action episodes "fell" within 8 s that way, 9 of 16 when only trunk, head and thighs count).

    PPO step size: with the paper's 10 x 128 at lr 3e-4 and a learned log-std, the log-std fell
    from -1 to -2 within 1.4 M steps and each update moved the policy by KL 1.8-4 (clip
    fraction 0.88, measured on a 4096-step batch of that checkpoint), so the policy never
    settled. Now: lr 1e-4 (MASS's default) and a log-std that is not learned but annealed by
    UniCon's policy variance controller from -1.0 to -1.5 over 5 M steps; KL per update then
    stays near 0.02-0.04 at first; but as the log-std falls the same step moves the policy further
    (KL 0.3-0.45 per update at log-std -1.5, 5.3 M steps). So the policy stops moving for the rest
    of an update once a minibatch's KL passes 0.1 (`kl_stop`; the value net trains on), measured
    on a fork of the lower-biped curriculum run at 5.3 M steps (box x0.5, gamma 0.99): after
    1.46 M more steps each, mean training episode 78 vs 67 control steps and mean time up on 100
    shapes of that box 5.1 s vs 3.1 s (`morphmimic evaluate --box-scale 0.5 --episode-s 30 --seed 7`).
    PD gains follow each shape's torque limits (`pd_gains_follow_torque`): with the base's gains
    the smallest bodies' PD sat at its limits. Measured on a fork of the lower-biped curriculum
    run at 41.0 M steps (whole box; 38.3% fall-down on 300 shapes, 30 s, at the fork): 3.85 M steps
    later, at the same iteration, 25.3% with the gains scaled against 44.0% for the run that kept
    the base's gains (smallest quarter of shapes by volume: 60% at the fork, then 36% against 72%).
    The manta asks each shape for the speed its own tracked stroke reaches (`swimmer_speed =
    "stroke_fit"`, `common.tasks.stroke_fit`): on 200 random shapes that speed is x0.27-x2.56 the
    length-scaled target (32.8% mean error for a perfectly tracked stroke), the fitted model's
    x0.42-x1.35 on held-out shapes (10.7% mean error). The fish keeps the length rule
    (its shapes' strokes: x0.78-x1.18 on 10 shapes). The manta also observes its offset from the
    reference's course (`observe_course`), on which its episodes end: its run without it drifted
    off course late in the episode (falls at 19.5 s on average, 40% of 50 shapes at 2.83 M
    steps), sideways as much as vertically. Variants for the ablations:
    "uniform" (k = 0), "nonorm" (no reward normalization), "fixedshape" (the base shape only)."""
    from common.policy import PolicyConfig
    from common.tasks.base import TaskConfig
    from common.tasks.body_config import BodyConfig
    from common.tasks.imitate_config import ImitateConfig
    from learner.ppo import PPOConfig

    task = TaskConfig(
        name=character, control_hz=30.0, sim_hz=480.0, episode_s=30.0,
        body=BodyConfig(parameterization=parameterization, vary_shape=variant != "fixedshape"),
        imitate=ImitateConfig(reward_normalization=variant != "nonorm", max_root_deviation=1.0 if swimmer else 0.0,
                              pd_gains_follow_torque=True,
                              swimmer_speed="stroke_fit" if character == "manta" else "length",
                              observe_course=character == "manta"),
    )
    return RunConfig(
        name=f"{character}-{variant}" if variant else character,
        total_env_steps=20_000_000,
        steps_per_iteration=4096,
        checkpoint_every=10,
        keep_checkpoints=200,
        vm_plot_every=20,
        task=task,
        policy=PolicyConfig(init_log_std=-1.0, learn_log_std=False, final_log_std=-1.5, log_std_anneal_steps=5_000_000),
        ppo=PPOConfig(epochs=10, minibatch=128, lr=1e-4, kl_stop=0.1),
        actors=ActorConfig(num_actors=2, envs_per_actor=8, unroll_length=32),
        sampler=SamplerConfig(k=0.0 if variant == "uniform" else ADAPTIVE_K, plot_params=plot),
    )


_SHAPE_TASKS = {
    "lower_biped": ("random", ("global_z", "global_x"), False, "lower-body biped walking (MASS walk), random global x per-segment scales"),
    "quadruped": ("random", ("global_z", "global_x"), False, "quadruped trotting (procedural), random global x per-segment scales"),
    "biped": ("leg_arm", ("leg_length", "arm_length"), False, "full biped walking (MASS walk), leg length vs arm length"),
    "fish": ("random", ("global_x", "global_z"), True, "fish swimming (procedural tail beat), random global x per-segment scales"),
    "manta": ("random", ("global_x", "global_y"), True, "manta ray swimming (procedural wing flap), random global x per-segment scales"),
}
_VARIANTS = {
    "": "adaptive shape sampling (k = 1)",
    "uniform": "ablation: uniform shape sampling (k = 0)",
    "nonorm": "ablation: no reward normalization",
    "fixedshape": "ablation: trained on the base shape only",
}
for _char, (_param, _plot, _swim, _text) in _SHAPE_TASKS.items():
    for _variant, _vtext in _VARIANTS.items():
        _cfg = _shape_preset(_char, _param, _plot, _variant, _swim)
        PRESETS[_cfg.name] = (f"{_text}; {_vtext}", _cfg)
PRESETS["lower_biped-tiny"] = (
    "two iterations of lower_biped for smoke tests",
    dataclasses.replace(
        PRESETS["lower_biped"][1], name="lower_biped-tiny", total_env_steps=2 * 1024, steps_per_iteration=1024,
        checkpoint_every=1, vm_plot_every=1, actors=ActorConfig(num_actors=1, envs_per_actor=4, unroll_length=32),
        sampler=SamplerConfig(k=ADAPTIVE_K, p_mcmc=1, n_mcmc=100, vm_fit_steps=10, plot_params=("global_z", "global_x")),
    ),
)


def _executor_preset(variant: str = "") -> RunConfig:
    """UniCon 2020's motion executor (METHOD.md B) on the DeepMimic humanoid over the train split
    of every clip that plays on it: torque actions, agent-centric observation with tau = 1, the
    five-term reward ended by any term below 0.1, reactive state initialization, 60 Hz control
    with 4 substeps (240 Hz physics), the motion balancer's clip draws, UniCon's policy variance
    controller and a KL penalty.

    Deviations from UniCon, for this 2-core CPU: a 3 x 256 network instead of 3 x 1024 (the
    learner's Adam step costs about 10x less per sample: DESIGN.md "Measured"). At equal wall time
    (`--preset executor-pd` from scratch, the two side by side for 20 min, 2026-12-02): 3 x 256
    collected 475,136 steps with the learner at 11% of wall time, 3 x 1024 417,792 steps with it
    at 77%, and their training returns were level (17.4 and 17.1 over the last 10 iterations):
    the wider network buys nothing yet and leaves the actors no room; 8192 transitions
    per update from 32 environments instead of 4096 agents x 64 steps, 5 epochs of 512.
    Action noise starts at log std -2 (0.14 of each effort factor, 52 N m at the hips) and the
    variance controller takes it to -2.5 over 20 M steps: at -1 (0.37, 143 N m) the random
    torques alone broke the joint-velocity term within one control step (40 starts on the
    tracked frame: every one ended at step 1), and the first 0.8 M steps of a run with it moved
    the mean return from 2.3 to 2.8 only; at -2 an untrained policy's return is 2.8 already.
    PPO step: at lr 2e-4 with the actors' weights up to two versions old, half of every batch
    fell outside the clip range (clip fraction 0.50-0.57) and the KL stop cut a quarter of the
    policy's minibatch steps; lr 5e-5 with decoupled PPO's proximal anchor (`--ppo.proximal-anchor`)
    held the clip fraction at 0.24-0.30 with every step taken, and its mean training return led
    at equal iterations (8.23 against 7.80 over iterations 50-59, 9.10 against 8.47 over 100-119:
    two runs side by side from scratch, 2026-12-02).
    The per-term rule watches the four pose terms; joint velocity stays in the reward (weight
    0.1) but ends nothing (`--task.executor.terminate-on`). Measured (30 starts on the tracked
    frame each, no offset, no wait): with all five watched, a zero PD residual - the humanoid's
    PD on the reference itself - ended at step 1 in the median (22 of 30 on joint_velocity;
    ankles and knees carry the error: the reset lifts the body out of the floor by 9 mm on
    average, up to 41 mm, and the landing jolts them), and random torques of std 0.05 ended
    30 of 30 at step 1 on it (std 0.03: 27 of 30); an inverse-dynamics torque oracle
    (`mj_inverse` on the reference acceleration) ended 28 of 30 there too. With the four pose
    terms watched, the zero PD residual tracks 14.5 steps in the median, 15 with noise std
    0.135, so an episode past the wait has something to learn from.
    The "pd" variant's PD damps toward the next frame's joint velocity, not toward rest
    (`pd_velocity_target`; since 2026-12-04): two arms forked from one PD checkpoint at 14.7 M
    steps and trained side by side to 32.8 M, with the switch and without, tracked 8.8-13.1%
    against 1.2-2.5% of train starts with all five terms above 0.1 and 17.5-22.5% against
    6.2-10.0% of held-out starts with the pose terms (six checkpoints each, iterations
    3700-4000; docs/executor.md). `--task.executor.no-pd-velocity-target` restores the old PD.
    The "pd" variant's ankles, shoulders and elbows have a rotor inertia of 0.1 kg m^2, not the
    builder's 0.01 (`ankle_armature`, `arm_armature`; since 2026-12-05): at the force limit the
    light segments' velocities flipped from substep to substep. Two arms forked from the shipped
    executor at 49.6 M steps and trained side by side to 56.5 M tracked 18.8-20.6% against
    8.8-10.0% of train starts with all five terms above 0.1 (four checkpoints each; docs/executor.md).
    `--task.executor.ankle-armature 0.01 --task.executor.arm-armature 0.01` restores the old body.
    The "pd" variant starts half its episodes on the tracked frame with the rule from the first
    step, as the evaluation does, and the other half reactively (`on_frame_share`; since
    2026-12-05, session 42): two arms from one checkpoint at 9.6 M steps, trained side by side to
    12.3 M, tracked 24.4-25.0% against 20.6-22.5% of train starts and 6.2% against 3.8-5.0% of
    held-out starts (four checkpoints each), 2.3 points lower against a projectile every 20 steps
    (`learner/pretrained/executor/ablation-mixed-starts/`). `--task.executor.on-frame-share 0` restores it.
    Variants for the ablations: "pd" (PD targets), "noterm" (the sum rule instead of per-term
    termination), "uniform" (uniform clip draws instead of the balancer), "norsis" (start on
    the tracked frame, no noise)."""
    from common.policy import PolicyConfig
    from common.tasks.base import TaskConfig
    from common.tasks.body_config import BodyConfig
    from common.tasks.executor_config import ExecutorConfig
    from common.tasks.executor_rewards import POSE_TERMS
    from learner.ppo import PPOConfig

    ex = ExecutorConfig(
        actuation="pd" if variant == "pd" else "torque",
        pd_velocity_target=variant == "pd",
        ankle_armature=0.1 if variant == "pd" else 0.01,
        arm_armature=0.1 if variant == "pd" else 0.01,
        termination="sum" if variant == "noterm" else "per_term",
        reactive_init=variant != "norsis",
        clip_draws="uniform" if variant == "uniform" else "balancer",
        terminate_on=POSE_TERMS,
        on_frame_share=0.5 if variant == "pd" else 0.0,
    )
    task = TaskConfig(name="executor", control_hz=60.0, sim_hz=240.0, episode_s=20.0,
                      body=BodyConfig(parameterization="height_thickness", vary_shape=False), executor=ex)
    return RunConfig(
        name=f"executor-{variant}" if variant else "executor",
        total_env_steps=50_000_000,
        steps_per_iteration=8192,
        checkpoint_every=10,
        keep_checkpoints=100,
        vm_plot_every=0,
        task=task,
        policy=PolicyConfig(hidden=(256, 256, 256), init_log_std=-2.0, learn_log_std=False, final_log_std=-2.5,
                            log_std_anneal_steps=20_000_000),
        ppo=PPOConfig(gamma=0.95, epochs=5, minibatch=512, lr=5e-5, kl_coef=0.2, kl_stop=0.1, proximal_anchor=True),
        actors=ActorConfig(num_actors=2, envs_per_actor=16, unroll_length=32),
        sampler=SamplerConfig(k=0.0, p_mcmc=1000, n_mcmc=100, vm_fit_steps=1),
    )


for _variant, _vtext in {"": "torque, per-term termination, balancer, reactive initialization",
                         "pd": "ablation: PD targets instead of torques", "noterm": "ablation: sum rule, no per-term termination",
                         "uniform": "ablation: uniform clip draws, no balancer", "norsis": "ablation: no reactive initialization"}.items():
    _cfg = _executor_preset(_variant)
    PRESETS[_cfg.name] = (f"UniCon motion executor on the DeepMimic humanoid over its clip library; {_vtext}", _cfg)
PRESETS["executor-tiny"] = (
    "two iterations of the executor for smoke tests",
    dataclasses.replace(
        PRESETS["executor"][1], name="executor-tiny", total_env_steps=2 * 1024, steps_per_iteration=1024, checkpoint_every=1,
        policy=dataclasses.replace(PRESETS["executor"][1].policy, hidden=(64, 64)),
        ppo=dataclasses.replace(PRESETS["executor"][1].ppo, minibatch=256),
        actors=ActorConfig(num_actors=1, envs_per_actor=4, unroll_length=32),
    ),
)
