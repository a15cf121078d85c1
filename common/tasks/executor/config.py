"""`ExecutorConfig`: the settings of UniCon's motion executor task (METHOD.md B), kept apart from
the shape tasks' fields; `TaskConfig.executor` carries it (`--task.executor.tau 2`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

from common.config_limits import Limit, above, at_least, between, check_limits, validated
from common.tasks.executor.rewards import TERMS


@dataclass(frozen=True)
@validated
class ExecutorConfig:
    clips: tuple[str, ...] = ()
    """Clip ids to track (empty: the `split` of every clip that plays on the humanoid,
    `common.motion.library.clips_for`)."""
    split: Literal["train", "test", "all"] = "train"
    """Which part of UniCon's category-aware 80/20 split (by frames, rare classes to test first)
    the task trains on when `clips` is empty."""
    split_seed: int = 0
    """Seed of the split (`common.motion.manifest.unicon_split`)."""
    library: Literal["core", "full"] = "core"
    """Which clips play on the humanoid: "core", the DeepMimic clips and the MASS clips retargeted
    onto it (what the executors shipped before 2026-12-07 trained on); "full", those and the Bandai Namco takes
    (`humanoid/bandai/*`, CC BY-NC 4.0: a checkpoint trained on them carries those terms), whose
    split is per class by takes (`common.motion.manifest.unicon_take_split`)."""
    mirror: bool = False
    """Also track every clip's left-right mirror image (`<id>~mirror`: the other hand and foot,
    turning the other way; `common.motion.mirror`), with its source's label and on its source's
    side of the split: twice the motions to learn from, none of them held out."""
    clip_draws: Literal["balancer", "uniform"] = "balancer"
    """balancer: clips are drawn by walking the class tree (UniCon 5.1, eq. 8); uniform: every
    clip equally likely (the ablation: the task relabels its clips so the balancer is flat)."""
    tau: int = 1
    """Target frames in the observation: X_t+1 .. X_t+tau (UniCon: 1); `preview` overrides it."""
    preview: tuple[int, ...] = ()
    """Control steps ahead of the target frames in the observation, e.g. 1 2 4 (a short preview
    as mjlab's and ProtoMotions' future frames, more of the future for fewer inputs than tau = 4);
    increasing, the first 1 (the frame the PD targets come from). Empty: 1 .. tau."""
    actuation: Literal["torque", "pd"] = "torque"
    """torque: the action is a torque per DOF, a in [-1, 1] times that DOF's effort factor
    (UniCon); pd: the action is a deviation from the next target frame's joint angles, tracked by
    the humanoid's PD (DeepMimic's gains), for the comparison."""
    effort_scale: float = 1.0
    """Multiplies every DOF's effort factor (`executor.EFFORT_70KG_NM` scaled to the body's mass)."""
    passive_damping: float = 0.1
    """torque: passive joint damping as a fraction of each joint's DeepMimic PD kd (hip 5,
    neck 1 N m s/rad at 0.1), integrated implicitly by MuJoCo. Ball joints have no limits, so
    without damping nothing takes energy out and random torques diverge the simulation within a
    few control steps; 0.1 is the least that kept them stable (`docs/executor.md`, "Two defaults
    and their measurements")."""
    pd_action_scale: float = 0.5
    """pd: rad of PD-target deviation per unit action."""
    pd_velocity_target: bool = False
    """pd: the PD's damping term tracks the next target frame's joint velocity, tau = kp (q~ - q)
    + kd (qdot~ - qdot), instead of pulling every joint toward rest, kd (0 - qdot) (DeepMimic's and
    MuJoCo's position actuator). Done by moving the position target by (kd / kp) qdot~, so the
    actuators are unchanged. It removes the lag that breaks the fast clips within a few control
    steps: the PD alone, with no policy, reaches 20.0% held-out pose success against 8.8%
    (`docs/experiments/2026-12-04-executor-pd-damping-target-velocity.md`)."""
    joint_velocity: Literal["instant", "step_mean"] = "instant"
    """What the joint-velocity term compares with the target frame's joint velocities (themselves
    a central difference of the clip's frames, `common.motion.reference`): instant, the
    simulator's joint velocities at the end of the control step (as UniCon writes it); step_mean,
    the mean over the control step, `mj_differentiatePos` of the joint angles before and after
    it, which leaves out the oscillation within the step of a joint pushed against its actuator's
    force limit. The default is instant: step_mean scores lower on the shipped PD executor (7.5
    against 10.6% train success, `docs/experiments/2026-12-04-executor-joint-velocity-term.md`)."""
    target_velocity_window: int = 1
    """The target frames' joint velocities (reward, observation and the PD's target velocity) are
    differences of the clip over +-this many control steps (1: +-1/60 s at 60 Hz; UniCon does not
    say). A wider window smooths the fast clips' target velocities, whose +-1 and +-3 step
    differences alone often differ by more than the velocity term's tolerance
    (`docs/experiments/2026-12-04-executor-joint-velocity-term.md`)."""
    ankle_armature: float = 0.01
    """Rotor inertia (kg m^2) of each ankle DOF (the builder gives every actuated DOF 0.01,
    `common.characters.builder.ARMATURE_KG_M2`). A foot in the air is light (0.0033 kg m^2 about
    its twist axis): whenever its PD asks for more than the 90 N m force limit, the clamped force
    is constant, MuJoCo's implicit integration no longer damps it, and the foot's velocity flips
    sign from one substep to the next; the instant velocity the joint-velocity term reads is then
    noise. A larger inertia damps that chatter; the `executor-pd` preset sets 0.1
    (`docs/experiments/2026-12-05-executor-armature-ankles.md`)."""
    arm_armature: float = 0.01
    """Rotor inertia (kg m^2) of each shoulder and elbow DOF, for the same reason as
    `ankle_armature` (an arm is light and its PD often at the limit); the `executor-pd` preset
    sets 0.1 (`docs/experiments/2026-12-05-executor-armature-ankles.md`)."""
    reference_filter_hz: float = 0.0
    """Cut-off (Hz) of the zero-phase low-pass filter every clip's tracks go through once, when
    the executor prepares the clip (`common.motion.clean.filter_qpos`: a Butterworth filter run
    forwards and backwards on a 120 Hz grid, root position and hinges directly, root orientation
    and ball joints in each frame's tangent space); the target velocities of the reward, the
    observation and the PD's lead are then the filtered tracks' derivatives. 0: off, the clips
    as recorded (every checkpoint trained before it). Measured on the 24 core clips at 7 Hz: the
    steps whose reference joint velocity changes by more than the joint-velocity term's whole
    tolerance (23 (rad/s)^2) in one control step fell from 45 to 29% on the DeepMimic backflip,
    64 to 44% on the MASS one, 87 to 59% on the spinkick, to under 2% on the walks and dances."""
    reference_floor: bool = False
    """Lift each frame of every clip, once when the executor prepares it, just enough that no
    geom of the humanoid is below the floor (`common.motion.clean.floor_offsets`; frames above
    it unchanged). Off: the clips as recorded, whose DeepMimic poses sink up to 133 mm into the floor."""
    pd_target_range: Literal["joint_limits", "widened"] = "joint_limits"
    """pd: the range the PD targets are clamped to (the actuators' ctrlrange). joint_limits: the
    humanoid's own (hinge limits, the builder's range per ball-joint axis), which the references
    exceed on 6.8% of the train steps and 20.2% of the held-out ones; widened: as MimicKit and PHC
    build their PD action bounds, a ball joint +-1.2 x its largest bound (at most pi), a hinge 1.4 x
    its half-range about its middle (`common.motion.clean.widen_ranges`); the joints' own limits
    are unchanged."""
    termination: Literal["per_term", "sum", "none"] = "per_term"
    """per_term: end the episode as soon as any of the five reward terms falls below `alpha`
    (UniCon's constrained objective, eq. 6); sum: only when the weighted sum falls below `alpha`
    (the ablation); none: only the time limit and simulator divergence end it."""
    terminate_on: tuple[str, ...] = TERMS
    """per_term: the terms the rule watches (UniCon: all five; the executor presets leave out
    joint_velocity, which stays in the reward: see `learner.presets._executor_preset`)."""
    alpha: float = 0.1
    """Tolerance of the termination rule (UniCon: 0.1 for every term)."""
    reward_weights: tuple[float, float, float, float, float] = (0.2, 0.2, 0.1, 0.4, 0.1)
    """w_pr, w_qr, w_pj, w_qj, w_wj (UniCon eq. 5)."""
    reward_scales: tuple[float, float, float, float, float] = (10.0, 2.0, 40.0, 2.0, 0.1)
    """Kernel scales k of exp(-k err): COM position (DeepMimic 10), root rotation (UniCon 2),
    joint positions (DeepMimic's 40 per four end effectors, see `unicon_rewards`), joint
    rotations (DeepMimic 2), joint velocities (DeepMimic 0.1)."""
    reactive_init: bool = True
    """Reactive state initialization (UniCon 5.2): start `rsis_frames` control steps away from
    the tracked frame with noise on root translation and velocities; off: start on the tracked
    frame exactly (DeepMimic's reference state initialization)."""
    rsis_frames: tuple[int, int] = (5, 10)
    """Range of the frame offset of reactive initialization, in control steps (either side)."""
    rsis_translation_m: float = 0.1
    """Reactive initialization: the root starts up to this far (horizontally, uniform in a disc)
    from the frame's root."""
    rsis_velocity_std: float = 0.5
    """Reactive initialization: Gaussian noise (m/s on the root, rad/s on every other DOF)."""
    catch_up_steps: int = 30
    """Training: the termination rule is suspended for this many control steps after an episode
    starts and after a reschedule (0: never, UniCon as written). UniCon says a 5-10 step offset
    "does not lead to early termination", but here an untrained policy breaks a term at once
    after every start (the offset alone puts r_pj below 0.1), so with the rule from the first
    step no episode lasts; 30 steps (0.5 s) let the dense reward teach tracking first
    (`docs/executor.md`, "Two defaults and their measurements"). Evaluation applies the rule
    from the first step."""
    on_frame_share: float = 0.0
    """Training: the share of episode starts placed on the tracked frame exactly, without noise
    and with the rule from the first step, as the evaluation starts its episodes; the other
    starts use `reactive_init` and the `catch_up_steps` wait (0: every start as those say).
    Reschedules at a clip's end are unchanged. The `executor-pd` preset sets 0.5: more success by
    UniCon's rule, a little less robustness to projectiles
    (`docs/experiments/2026-12-05-executor-success-plateau-and-mixed-starts.md`)."""
    catch_up_ends: Literal["after_steps", "on_track"] = "after_steps"
    """When the wait of `catch_up_steps` ends: after_steps, always after that many control steps;
    on_track, also at the first step on which every watched term is at or above `alpha` (the
    character has caught up; from then on the rule applies, as UniCon's would). Most starts are
    on track within the wait and lose it again inside it, so after_steps trains on states the
    rule would already have ended; on_track changed no evaluation figure
    (`docs/experiments/2026-12-03-executor-where-training-episodes-end.md`)."""
    action_rate_weight: float = 0.0
    """Weight w of an action-rate penalty subtracted from the step's reward: w x the mean over
    actuators of (a_t - a_t-1)^2, the actions as applied (pd: clipped to +-3; torque: +-1; a_-1 = 0
    at a start), as mjlab's and ProtoMotions' action_rate_l2 (not in UniCon). From a perfect state
    the shipped policy's first action broke the velocity term where its PD alone did not; the
    penalty makes jerks cost. 0: off (every checkpoint trained before it). The step's reward is
    then in [-36 w, 1] (`rewards.reward_range`)."""
    previous_action_obs: bool = False
    """Append the previous control step's action as applied (zeros after a start) to the
    observation, as mjlab and ProtoMotions do, so the policy can see what the action-rate penalty
    compares with. Off: the observation of every checkpoint trained before it."""
    at_clip_end: Literal["reschedule", "stop"] = "reschedule"
    """What the dataset scheduler does when a clip's end is reached: reschedule a random clip
    and frame (training), or stop, which truncates the episode (evaluation)."""
    speed: float = 1.0
    """Playback speed of the target frames (robustness: 0.4 .. 1.6)."""
    projectile: bool = False
    """Add a projectile body to the scene (robustness); parked out of the way until thrown."""
    reward_normalization: bool = True
    """With `--task.body.vary-shape`: Won & Lee's reward normalization across body sizes
    (METHOD.md A) on the two position terms, their squared errors divided by (lbar / lbar0)^2,
    the body's mean leg length over the base humanoid's (`rewards.size_normalized_errors`, a
    reconstruction); the base shape's factor is 1. Off: a metre counts the same on every body.
    Without vary-shape nothing is normalized."""
    shape_cache: int = 4
    """With `--task.body.vary-shape`: bodies (the shaped humanoid and its simulated model, about
    2.3 MB each) each environment keeps (LRU, `bodies.ShapedBodies`): a shape met again (the
    sampler's buffer repeats its shapes) skips the build, 5-7 ms."""
    reference_cache: int = 32
    """With `--task.body.vary-shape`: clips retargeted onto a body kept per (clip, shape) (LRU,
    `bodies.ShapedReferences`, shared by the environments of an actor's batch): a hit skips the
    retargeting, 12 ms for the 1.3 s DeepMimic walk, 25-32 ms for a 5 s take (measured on two
    busy cores). An entry holds the clip's frames and the body's model, about 1.5 MB for a 5 s take."""

    FLAG_PREFIX: ClassVar[str] = "task.executor"
    LIMITS: ClassVar[dict[str, Limit]] = {
        "split_seed": at_least(0), "tau": between(1, 60, integer=True), "effort_scale": between(0, 100, lo_open=True),
        "passive_damping": between(0, 100), "pd_action_scale": between(0, 10, lo_open=True), "alpha": between(0, 1, lo_open=True, hi_open=True),
        "reward_weights": at_least(0, False), "reward_scales": above(0), "rsis_frames": at_least(0),
        "rsis_translation_m": at_least(0, False), "rsis_velocity_std": at_least(0, False), "catch_up_steps": at_least(0),
        "on_frame_share": between(0, 1),
        "speed": between(0.05, 10), "ankle_armature": between(0, 10), "arm_armature": between(0, 10),
        "target_velocity_window": between(1, 30, integer=True), "reference_filter_hz": between(0, 30),
        "action_rate_weight": between(0, 10), "preview": between(1, 60, integer=True),
        "shape_cache": between(1, 4096, integer=True), "reference_cache": between(1, 65536, integer=True),
    }
    """Allowed values of the numeric fields (`common.config_limits`)."""

    @property
    def observed_offsets(self) -> tuple[int, ...]:
        """Control steps ahead of each observed target frame: `preview`, else 1 .. `tau`."""
        return self.preview or tuple(range(1, self.tau + 1))

    def validate(self) -> None:
        """ValueError naming the first value outside what is allowed."""
        check_limits(self)
        p = self.preview
        if p and (p[0] != 1 or any(b <= a for a, b in zip(p, p[1:])) or p[-1] > 60):
            raise ValueError(f"--task.executor.preview = {' '.join(map(str, p))} is not allowed: give increasing "
                             "control-step offsets starting at 1, at most 60 (e.g. 1 2 4), or none for 1 .. tau")
        if len(self.rsis_frames) != 2:
            raise ValueError(f"--task.executor.rsis-frames = {self.rsis_frames} is not allowed: give two integers, low high")
        lo, hi = self.rsis_frames
        if not lo <= hi:
            raise ValueError(f"--task.executor.rsis-frames = {self.rsis_frames} must be low <= high")
        bad = [t for t in self.terminate_on if t not in TERMS]
        if bad or not self.terminate_on or len(set(self.terminate_on)) != len(self.terminate_on):
            raise ValueError(f"--task.executor.terminate-on = {self.terminate_on}: give one or more distinct terms of "
                             f"{', '.join(TERMS)}")
        if len(self.reward_weights) != 5 or len(self.reward_scales) != 5:
            raise ValueError("--task.executor.reward-weights and --task.executor.reward-scales take 5 values each")
        if not sum(self.reward_weights) > 0:
            raise ValueError(f"--task.executor.reward-weights = {self.reward_weights}: give at least one weight > 0")
