"""`ExecutorEnv`: UniCon's low-level motion executor (Wang et al. 2020; METHOD.md B) on the
DeepMimic humanoid, over a whole clip library.

- Targets come from a `Scheduler` (`schedulers/`); training uses the `DatasetScheduler`: the
  clip the sampler drew for the episode, from a random frame, rescheduled at the clip's end
  (`ExecutorConfig.at_clip_end`) to a clip and frame drawn by the environment's `ClipManager`
  (`clip_manager`: the task's clips under the motion balancer, without the sampler's adaptive
  weights, which stay in the sampler service).
- Observation: s_t = [shape params, o(X_now), o(X~_t+1), y(X~_t+1), ... up to tau (or the
  `preview` offsets), the previous action with `previous_action_obs`]
  (`executor_obs.py`): agent-centric, unchanged by where the character stands or faces.
- Action (`ExecutorConfig.actuation`): torques, a in [-1, 1] per DOF times its effort factor
  (`EFFORT_70KG_NM`, UniCon's 50-600 N m for its 70 kg humanoid, scaled by mass to this one);
  or PD targets q~_t+1 + scale a with the humanoid's DeepMimic gains, for the comparison.
- Reward and termination (`executor_rewards.py`): the five terms with UniCon's weights; the
  episode ends as soon as any term is below alpha = 0.1 (switchable), on simulator divergence,
  and is truncated at the time limit or when a stopping scheduler runs out.
- Reactive state initialization (UniCon 5.2): the character starts 5-10 control steps away from
  the tracked frame with noise on root translation and velocities (switchable). In training the
  termination rule waits `catch_up_steps` (30) control steps after a start or a reschedule (a
  reconstruction, see `ExecutorConfig.catch_up_steps`), or, with `catch_up_ends = "on_track"`,
  until every watched term is back above alpha; evaluation applies it from the start.
- 60 Hz control with 4 substeps (240 Hz physics), as UniCon (`executor` preset).

The humanoid's shape parameters are the episode parameters, first in the observation. They are
pinned to the base shape unless `--task.body.vary-shape` widens them to the parameterization's
box (Won & Lee 2019, METHOD.md A): each reset then builds the body of the episode's shape and
retargets its clips onto it (`bodies.py`: both cached), and the two position terms of the reward
are normalized by the body's size (`rewards.size_normalized_errors`).

Robustness hooks (zero-shot tests, UniCon 8.5): `scale_mass` makes the body heavier or lighter,
`throw_projectile` throws the next of the optional projectile balls (`ExecutorConfig.projectile`) at it.
"""

from __future__ import annotations

import functools
import math
import operator
from dataclasses import dataclass
from typing import Sequence

import mujoco
import numpy as np

from common.characters import Character, CharacterFactory, load_character
from common.characters.character import extent
from common.characters.mass import scale_body_mass
from common.characters.morph import lift_out_of_floor
from common.characters.presets.humanoid import GAINS
from common.motion.clean import clean_motion, widen_ranges
from common.motion.clip_manager import ClipManager
from common.motion.errors import ClipError
from common.motion.library import MotionLibrary, clips_for
from common.motion.manifest import Manifest, load_manifest, unicon_split, unicon_take_split
from common.motion.mirror import MIRROR_SUFFIX, mirrored_id, source_id
from common.motion.reference import CharacterMotion
from common.motion.retarget import RetargetConfig
from common.params import ParamSpace
from common.tasks.base import _DIVERGENCE_WARNINGS, TaskConfig, diverged_step
from common.tasks.content_bounds import OBS_MAX_ABS_LIMIT, ContentBounds
from common.tasks.executor import rewards as rw
from common.tasks.executor.bodies import ShapedBodies, ShapedBody, ShapedReferences
from common.tasks.executor.observations import BodyKin, agent_features, kinematics_from_arrays, observation_of
from common.tasks.executor.schedulers.base import DatasetScheduler, Scheduler, TargetFrame
from common.tasks.observations import JointLayout
from common.tasks.shape_params import shape_param_space

CHARACTER = "humanoid"
EFFORT_70KG_NM = {
    "chest": 600.0, "neck": 100.0, "hip": 600.0, "knee": 400.0, "ankle": 300.0, "shoulder": 300.0, "elbow": 150.0,
}
"""Effort factor (N m per unit action) of each joint's DOF for a 70 kg humanoid, within UniCon's
range of 50-600 (7.2: the paper gives the range, not the table, so the split is a
reconstruction: strongest at hips and trunk, weakest at the neck and elbows). The task scales
them by body mass / 70 kg (45 kg: 386 N m at the hips, 64 N m at the neck), 1.6-2.1x the
DeepMimic PD torque limits of the same joints."""
UNICON_MASS_KG = 70.0
PROJECTILE = {"mass_kg": 2.0, "radius_m": 0.08}
"""The projectile of the robustness test: a 2 kg ball, 16 cm across (see `throw_projectile`)."""
PROJECTILES = 24
"""Balls in a scene built with `ExecutorConfig.projectile`, thrown in turn, so one can be thrown
every control step although each flies for about 12 steps (2 m at 10 m/s, 60 Hz)."""
MAX_UNDRAINED_SEGMENTS = 4096
"""Clip segments an environment keeps for `drain_segments`; older ones are dropped when nobody drains."""
PROJECTILE_LIFE_STEPS = 60
"""A thrown ball is parked again this many control steps (1 s) after its throw."""
PARKED = np.array([0.0, 0.0, -50.0])
"""Where parked balls wait: below the floor, weightless (gravcomp) and without contacts."""


@functools.lru_cache(maxsize=None)
def _manifest() -> Manifest:
    return load_manifest()


BANDAI_PREFIX = "humanoid/bandai/"
"""Manifest ids of the Bandai Namco takes on the humanoid (`common.motion.bandai`)."""


def humanoid_clips(mirror: bool = False, library: str = "core") -> list[tuple[str, str]]:
    """(clip_id, label) of every manifest clip of `library` ("core" or "full", see
    `ExecutorConfig.library`) that plays on the humanoid as it is; with `mirror`, each followed
    by its left-right mirror image (`<id>~mirror`, the same label; mirror.py)."""
    if library not in ("core", "full"):
        raise ValueError(f"clip library {library!r} is not one of core, full")
    pairs = [(c, label) for c, label in clips_for(CHARACTER, _manifest()) if library == "full" or not c.startswith(BANDAI_PREFIX)]
    return _with_mirrors(pairs) if mirror else pairs


def _with_mirrors(pairs: list[tuple[str, str]]) -> list[tuple[str, str]]:
    return [p for c, label in pairs for p in ((c, label), (mirrored_id(c), label))]


def executor_clips(cfg: TaskConfig) -> list[tuple[str, str]]:
    """(clip_id, label) the task tracks: `cfg.executor.clips`, else the configured split; with
    `clip_draws="uniform"` every label is "root/all", so the motion balancer draws uniformly."""
    pairs = labelled_clips(cfg)
    if cfg.executor.clip_draws == "uniform":
        return [(c, "root/all") for c, _ in pairs]
    return pairs


def labelled_clips(cfg: TaskConfig) -> list[tuple[str, str]]:
    """(clip_id, manifest label) the task tracks (see `executor_clips`). The split is drawn over
    the manifest's clips; with `mirror` each clip's mirror image joins it on its side, so a
    held-out motion is never learnt through its mirror. Named clips may be mirrored ids."""
    ex = cfg.executor
    plain = humanoid_clips(library=ex.library)
    if ex.clips:
        labels = dict(_with_mirrors(plain))
        unknown = [c for c in ex.clips if c not in labels]
        if unknown:
            raise ValueError(f"clips {unknown} do not play on the humanoid; choose from: {', '.join(c for c, _ in plain)} "
                             f"(each also as <id>{MIRROR_SUFFIX}, its mirror image)")
        named = list(ex.clips)
        if ex.mirror:
            named += [mirrored_id(c) for c in ex.clips if mirrored_id(c) not in named]
        return [(c, labels[c]) for c in named]
    every = _with_mirrors(plain) if ex.mirror else plain
    if ex.split == "all":
        return every
    manifest = _manifest()
    core = Manifest(tuple(manifest.by_id(c) for c, _ in plain if not c.startswith(BANDAI_PREFIX)))
    split = unicon_split(core, seed=ex.split_seed)
    keep = set(split.train if ex.split == "train" else split.test)
    takes = Manifest(tuple(manifest.by_id(c) for c, _ in plain if c.startswith(BANDAI_PREFIX)))
    if takes.entries:
        by_take = unicon_take_split(takes, seed=ex.split_seed)
        keep |= set(by_take.train if ex.split == "train" else by_take.test)
    return [(c, lab) for c, lab in every if source_id(c) in keep]


def torque_actuation(model: mujoco.MjModel, efforts: np.ndarray) -> None:
    """Turn every actuator of `model` into a motor: force = effort * ctrl, ctrl in [-1, 1],
    no stiffness or damping (the policy owns them), in place. efforts `[nu]` N m."""
    model.actuator_gaintype[:] = mujoco.mjtGain.mjGAIN_FIXED
    model.actuator_biastype[:] = mujoco.mjtBias.mjBIAS_NONE
    model.actuator_gainprm[:] = 0.0
    model.actuator_gainprm[:, 0] = efforts
    model.actuator_biasprm[:] = 0.0
    model.actuator_ctrlrange[:] = [-1.0, 1.0]
    model.actuator_ctrllimited[:] = 1
    model.actuator_forcerange[:, 0] = -efforts
    model.actuator_forcerange[:, 1] = efforts
    model.actuator_forcelimited[:] = 1


def passive_damping(model: mujoco.MjModel, fraction: float) -> None:
    """Set each actuated DOF's joint damping to `fraction` x its DeepMimic PD kd, in place
    (see `ExecutorConfig.passive_damping` for why torque control needs it)."""
    for a in range(model.nu):
        j = int(model.actuator_trnid[a, 0])
        width = 3 if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL else 1
        dof = int(model.jnt_dofadr[j])
        model.dof_damping[dof : dof + width] = fraction * GAINS[model.joint(j).name.split("_")[-1]][1]


def set_armature(spec: mujoco.MjSpec, part: str, armature: float) -> None:
    """Set the rotor inertia `armature` (kg m^2) of the joints whose last name word is `part`
    (`ankle`: both ankles, every DOF of each) in a spec before it compiles, so that what MuJoCo
    derives from it at compile time agrees; ValueError when no joint is one (see
    `ExecutorConfig.ankle_armature` for why the ankles need more than the builder's)."""
    joints = [j for j in spec.joints if j.name.split("_")[-1] == part]
    if not joints:
        raise ValueError(f"no {part!r} joint in this model to set the armature of")
    for joint in joints:
        joint.armature = armature


def pd_lead_s(model: mujoco.MjModel) -> np.ndarray:
    """kd / kp `[nu]` (s) of the PD's position actuators (gain kp, bias -kp q - kd qdot)."""
    return -model.actuator_biasprm[:, 2] / model.actuator_gainprm[:, 0]


def pd_target(layout: JointLayout, frame: TargetFrame, lead_s: np.ndarray | None = None) -> np.ndarray:
    """The PD targets `[nu]` of a zero action (`pd_targets` of one frame)."""
    return pd_targets(layout, frame.qpos, frame.qvel, lead_s)


def pd_targets(layout: JointLayout, qpos: np.ndarray, qvel: np.ndarray, lead_s: np.ndarray | None = None) -> np.ndarray:
    """The PD targets `[..., nu]` of a zero action for target frames `qpos` `[..., nq]`, `qvel`
    `[..., nv]`: the frames' joint angles (ball joints as rotation vectors); with `lead_s`
    (`pd_lead_s`, the `pd_velocity_target` switch) plus the frames' joint velocities times
    kd / kp, which turns the actuators' damping kd (0 - qdot) into kd (qdot~ - qdot): the PD
    with a target velocity (Tan et al. 2011); DeepMimic's has none."""
    target = layout.to_vector(qpos)
    if lead_s is not None:
        target = target + lead_s * qvel[..., 6 : 6 + len(lead_s)]
    return target


def effort_factors(model: mujoco.MjModel, mass_kg: float, scale: float = 1.0) -> np.ndarray:
    """`[nu]` effort factors: EFFORT_70KG_NM by joint (actuator names `<joint>` or
    `<joint>_x|y|z`, the joint's last word picks the row) times mass / 70 kg times `scale`."""
    out = np.zeros(model.nu)
    for a in range(model.nu):
        joint = model.joint(int(model.actuator_trnid[a, 0])).name
        part = joint.split("_")[-1]
        if part not in EFFORT_70KG_NM:
            raise ValueError(f"actuator {model.actuator(a).name!r}: no effort factor for joint kind {part!r}")
        out[a] = EFFORT_70KG_NM[part] * mass_kg / UNICON_MASS_KG * scale
    return out


class TargetTable:
    """What a step reads of its environments' target frames, per schedule row: each
    environment's `DatasetScheduler` table (`kinematics_at`) of at most `rows` rows, kept in
    slot i of arrays `[N, rows, ...]`: the frames' `BodyKin` fields (`pos`, `rot`, `lin`, `ang`,
    `com`), what the step derives from a frame alone (`rel`: `BodyKin.root_offsets`;
    `features`: o(X~), `agent_features`), `qpos`, `qvel`, the PD targets of a zero action (`pd`,
    `pd_targets`; pd actuation only), and `next_row` `[N]`: the row of the frame one control
    step ahead as of the last observation (what the next step's PD targets come from); per
    environment, rows 0..R-1 of its slot are the R rows its scheduler last filled. An
    `ExecutorBatch`'s environments
    share one, so a step gathers every environment's targets with one index per array; a
    single environment has one of its own (N = 1). Every row holds what the frame gives alone,
    so a gather is the per-frame values bit for bit."""

    def __init__(self, n: int, rows: int, bodies: int, nq: int, nv: int, nu: int, pd: bool):
        self.rows = rows
        self.pos, self.lin, self.ang = (np.zeros((n, rows, bodies, 3)) for _ in range(3))
        self.rot = np.zeros((n, rows, bodies, 3, 3))
        self.com = np.zeros((n, rows, 3))
        self.rel = np.zeros((n, rows, bodies - 1, 3))
        self.features = np.zeros((n, rows, 13 + 15 * (bodies - 1)))
        self.qpos, self.qvel = np.zeros((n, rows, nq)), np.zeros((n, rows, nv))
        self.pd = np.zeros((n, rows, nu)) if pd else None
        self.next_row = np.zeros(n, np.intp)

    def targets(self, slots: np.ndarray, rows: np.ndarray) -> BodyKin:
        """`BodyKin` `[M, R]` of rows `[M, R]` of slots `[M]`."""
        at = (slots[:, None], rows)
        return BodyKin(self.pos[at], self.rot[at], self.lin[at], self.ang[at], self.com[at])

    def copy_slot(self, other: "TargetTable", mine: int, theirs: int) -> None:
        """Copy slot `theirs` of `other` into slot `mine` of this table."""
        for name in ("pos", "rot", "lin", "ang", "com", "rel", "features", "qpos", "qvel", "pd", "next_row"):
            if getattr(self, name) is not None:
                getattr(self, name)[mine] = getattr(other, name)[theirs]


class _RowIndex:
    """The table `_fill_targets` hands the `DatasetScheduler`: indexing it gives back the index,
    so `kinematics_at` returns the rows' places in the environment's `TargetTable` slot."""

    def __getitem__(self, index: np.ndarray) -> np.ndarray:
        return index


_ROW_INDEX = _RowIndex()


class ExecutorEnv:
    """Gymnasium-style environment (`common.tasks.base.Env`); see the module docstring."""

    _table: TargetTable | None = None
    _slot = 0
    _slots = np.zeros(1, np.intp)
    leg_ratio = 1.0

    @staticmethod
    def param_space(cfg: TaskConfig) -> ParamSpace:
        """The humanoid's shape parameters (`cfg.body.parameterization`): its box with
        `cfg.body.vary_shape` (shrunk by `shape_box_scale`), else pinned to the base shape."""
        return shape_param_space(CHARACTER, cfg.body, 1.0 / cfg.sim_hz)

    @staticmethod
    def clips(cfg: TaskConfig) -> list[tuple[str, str]]:
        return executor_clips(cfg)

    @staticmethod
    def content_bounds(cfg: TaskConfig) -> ContentBounds:
        """A step's reward range (`rewards.reward_range`): UniCon's weighted sum of five terms in
        (0, 1] is in [0, sum w], less at most the largest action-rate penalty."""
        ex = cfg.executor
        lo, hi = rw.reward_range(ex.reward_weights, ex.action_rate_weight, ex.actuation)
        return ContentBounds(reward_min=lo, reward_max=hi,
                             obs_max_abs=OBS_MAX_ABS_LIMIT, episode_steps=cfg.episode_steps)

    def __init__(self, cfg: TaskConfig, seed: int = 0, like: ExecutorEnv | None = None):
        """`like`: an environment of the same `cfg` whose compiled model (unless projectiles or
        `vary_shape` make the models per environment), clip library, retargeted clips and clip
        manager this one shares (`ExecutorBatch`); it behaves as one built alone."""
        self.cfg, self.ex = cfg, cfg.executor
        self.rng = np.random.default_rng(seed)
        self._segments: list[tuple[str, bool, float]] = []  # ended clip segments not yet drained
        self._segment_clip = ""
        self.space = self.param_space(cfg)
        self.dt = 1.0 / cfg.control_hz
        if self.ex.actuation not in ("torque", "pd"):
            raise ValueError(f"actuation {self.ex.actuation!r} is not one of torque, pd")
        base = like.base_character if like is not None else load_character(CHARACTER, timestep_s=1.0 / cfg.sim_hz)
        self.base_character = base
        """The humanoid at its base shape (what clips are prepared on)."""
        self.mass_factor = 1.0
        """`scale_mass`'s factor, kept for every body the environment switches to."""
        self.body: ShapedBody | None = None
        """The episode's body with `vary_shape` (None: the base humanoid, always)."""
        self._bodies = (ShapedBodies(CharacterFactory(CHARACTER, cfg.body.parameterization, timestep_s=1.0 / cfg.sim_hz),
                                     base, self._compile, self.ex.shape_cache) if cfg.body.vary_shape else None)
        if self._bodies is None:
            model = like.model if like is not None and not self.ex.projectile else self._compile(base)
            self._simulate(base, model, like.ref_data if like is not None else mujoco.MjData(base.model),
                           model.body_mass.copy(), model.body_inertia.copy())
        else:
            self._use_body(self._bodies.get(self.space.default_array))
        self.nq, self.nv, self.nu = self.ref_model.nq, self.ref_model.nv, self.ref_model.nu
        self.layout = JointLayout(self.ref_model)
        self.bodies = np.arange(1, self.ref_model.nbody)
        self.body_slice = slice(1, self.ref_model.nbody)
        """The character's bodies (ids, root first; as a slice): what `BodyKin` holds."""
        self.clip_list = executor_clips(cfg)
        if not self.clip_list:
            raise ValueError(f"no clips to track for split {self.ex.split!r} (seed {self.ex.split_seed})")
        self.library = like.library if like is not None else MotionLibrary()
        self._motions: dict[str, CharacterMotion] = like._motions if like is not None else {}
        """Each clip as prepared on the base humanoid (`_source`)."""
        self._references = (None if self._bodies is None else like._references if like is not None else
                            ShapedReferences(self._source, base, RetargetConfig(), self.ex.reference_floor,
                                             self.ex.reference_cache))
        """With `vary_shape`: the clips retargeted onto bodies, by (clip, shape), shared by a batch."""
        self.clip_manager = (like.clip_manager if like is not None else
                             ClipManager(self.clip_list, duration_s=lambda c: self._source(c).duration_s))
        """Draws the clip and start of every schedule the environment begins itself (a reset without
        a clip, a reschedule), by the motion balancer's probabilities. NOTE: unweighted: the
        sampler's adaptive clip weights (`sampler/clip_outcomes.py`) shape the episode's first clip
        (the sampler's draw) but not the reschedules, since draws reach the actors without them."""
        lookback = self.ex.rsis_frames[1] + 1
        self.scheduler = DatasetScheduler(self.ref_model, self._motion, self.clip_manager, None, self.dt,
                                          speed=self.ex.speed, at_end=self.ex.at_clip_end, lookback=lookback,
                                          lookahead=self.ex.observed_offsets[-1] + 1, velocity_window=self.ex.target_velocity_window,
                                          kinematics=self._fill_targets)
        self._begun: Scheduler | None = None
        """The scheduler `reset` last began (a swapped-in one is begun at the next reset)."""
        self.balls = [self.model.body(f"projectile{i}").id for i in range(PROJECTILES)] if self.ex.projectile else []
        self._thrown_at = [-1] * len(self.balls)
        self._next_ball = 0
        self.data = mujoco.MjData(self.model)
        obs, _ = self.reset(seed, self.space.default_array)
        self.obs_dim = int(obs.shape[0])
        self.act_dim = int(self.nu)

    def _compile(self, ch) -> mujoco.MjModel:
        """The simulated model: the character with the configured armatures, projectile balls and
        actuation (torque: motors with effort factors and passive damping; pd: the builder's PD,
        its target ranges widened as MimicKit and PHC do with `pd_target_range = "widened"`)."""
        spec = ch.spec.copy()
        if self.ex.projectile:
            for i in range(PROJECTILES):
                ball = spec.worldbody.add_body(name=f"projectile{i}", pos=list(PARKED), gravcomp=1.0)
                ball.add_freejoint(name=f"projectile{i}")
                ball.add_geom(name=f"projectile{i}", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[PROJECTILE["radius_m"], 0, 0],
                              mass=PROJECTILE["mass_kg"], rgba=[0.9, 0.3, 0.2, 1.0], contype=0, conaffinity=0)
        set_armature(spec, "ankle", self.ex.ankle_armature)
        for part in ("shoulder", "elbow"):
            set_armature(spec, part, self.ex.arm_armature)
        model = spec.compile()
        if self.ex.actuation == "pd" and self.ex.pd_target_range == "widened":
            model.actuator_ctrlrange[:] = widen_ranges(model)
        if self.ex.actuation == "torque":
            torque_actuation(model, effort_factors(model, float(ch.mass_kg), self.ex.effort_scale))
            passive_damping(model, self.ex.passive_damping)
        return model

    def _simulate(self, ch: Character, model: mujoco.MjModel, ref_data: mujoco.MjData, body_mass: np.ndarray,
                  body_inertia: np.ndarray) -> None:
        """Simulate character `ch` as `model` (its compiled masses and inertias `body_mass`,
        `body_inertia`), its target frames' kinematics on `ch.model` with `ref_data`."""
        self.character = ch
        self.ref_model = ch.model
        self.ref_data = ref_data
        self._target_kin_memo: dict[bytes, BodyKin] = {}
        self.model = model
        self.base_mass, self.base_inertia = body_mass, body_inertia
        self.mass_kg = float(ch.mass_kg)
        if self.ex.actuation == "torque":
            self.efforts = effort_factors(self.model, self.mass_kg, self.ex.effort_scale)
        self.pd_lead_s = pd_lead_s(self.model) if self.ex.actuation == "pd" and self.ex.pd_velocity_target else None

    def _use_body(self, body: ShapedBody) -> None:
        """Switch to `body` (`vary_shape`): its models, a new MjData, `scale_mass`'s factor and the
        reward's size normalization; nothing when it is the body in use."""
        if body is self.body:
            return
        self.body = body
        self._simulate(body.character, body.model, body.ref_data, body.body_mass, body.body_inertia)
        self.data = mujoco.MjData(self.model)
        if self.mass_factor != 1.0:
            self.scale_mass(self.mass_factor)
        self.leg_ratio = body.norm.leg_ratio if self.ex.reward_normalization else 1.0
        """lbar / lbar0 of the body the position terms are normalized by (`rewards.size_normalized_errors`)."""

    def _source(self, clip_id: str) -> CharacterMotion:
        """The clip as prepared on the base humanoid (`_prepare`), once per clip."""
        if clip_id not in self._motions:
            # NOTE: played once through, never wrapped: the scheduler reschedules at the end
            # anyway, and most "looping" mocap does not close (humanoid3d_walk's shoulders turn
            # 0.5 rad across its seam), so a wrap put 14 rad/s spikes into the target velocities.
            clip = self.library.clip(clip_id).with_(loop=False)
            self._motions[clip_id] = self._prepare(CharacterMotion.from_clip(clip, self.base_character.model))
        return self._motions[clip_id]

    def _motion(self, clip_id: str) -> CharacterMotion:
        """The clip as the episode's body tracks it: the prepared clip (`_source`) on the base
        humanoid; with `vary_shape`, retargeted onto the body (`ShapedReferences`)."""
        if self._references is None:
            return self._source(clip_id)
        return self._references.get(clip_id, self.body)

    def _prepare(self, motion: CharacterMotion) -> CharacterMotion:
        """A clip as the executor tracks it, cleaned once (`ExecutorConfig.reference_filter_hz`,
        `reference_floor`; `common.motion.clean.clean_motion`): the same motion when both are off.
        With `vary_shape` the floor is left to each body's retargeted clip (`ShapedReferences`)."""
        return clean_motion(motion, self.ex.reference_filter_hz, self.ex.reference_floor and self._references is None)

    def register_clip(self, clip_id: str, clip) -> None:
        """Make a clip that is not in the task's set trackable by name (`reset(..., clip_id)`),
        e.g. a file the project has never seen; it is never drawn. Raises ClipError when the
        clip's joints do not fit the humanoid."""
        if clip.character and clip.character != CHARACTER:
            raise ClipError(f"clip is for the {clip.character!r} character, not {CHARACTER!r}; import it onto the "
                            "humanoid first (morphmimic motion import ... --character humanoid)", path=clip_id)
        motion = CharacterMotion.from_clip(clip.with_(loop=False), self.base_character.model)
        self._motions[clip_id] = self._prepare(motion)
        if self._references is not None:
            self._references.forget(clip_id)
        if hasattr(self.scheduler, "extra_ids"):
            self.scheduler.extra_ids.add(clip_id)

    def use_scheduler(self, scheduler: Scheduler) -> None:
        """Drive the targets with another scheduler (UniCon's run-time schedulers: dataset,
        stitch, keyboard, video; `scheduler_factory.make_scheduler` builds them for this env).
        The next `reset` begins it (later resets begin or resume it, see `reset`); the old one is
        not closed (its owner closes it)."""
        for name in ("begin", "frame", "advance", "status"):
            if not callable(getattr(scheduler, name, None)):
                raise TypeError(f"{type(scheduler).__name__} is not a Scheduler: it has no {name}()")
        self.scheduler = scheduler

    # ---- state ----

    def views(self, data: mujoco.MjData, names: tuple[str, ...]) -> tuple[np.ndarray, ...]:
        """`data`'s arrays `names` (attribute paths; numpy views of its memory, which follow
        every step and reset), made once per MjData the environment reads. NOTE: each attribute
        read builds a new numpy wrapper (about 0.5 us), and a step read some 100 of them."""
        cache = self.__dict__.setdefault("_views", {})
        hit = cache.get(names)
        if hit is None or hit[0] is not data:
            hit = cache[names] = (data, tuple(operator.attrgetter(name)(data) for name in names))
        return hit[1]

    def reference_kinematics(self, qpos: np.ndarray, qvel: np.ndarray) -> BodyKin:
        """`BodyKin` `[R]` of R frames of the character (`qpos` `[R, nq]`, `qvel` `[R, nv]`): the
        same MuJoCo calls on each frame as on the character (`mj_kinematics`, `mj_comPos`,
        `mj_comVel`), run on the reference model. The `DatasetScheduler` calls it on a table of
        schedule rows at a time (`DatasetScheduler.kinematics_at`)."""
        d, m, n = self.ref_data, self.ref_model, len(qpos)
        xpos, xmat = np.empty((n, m.nbody, 3)), np.empty((n, m.nbody, 9))
        cvel, com = np.empty((n, m.nbody, 6)), np.empty((n, m.nbody, 3))
        d_qpos, d_qvel, d_xpos, d_xmat, d_cvel, d_com = self.views(d, ("qpos", "qvel", "xpos", "xmat", "cvel", "subtree_com"))
        for r in range(n):
            d_qpos[:], d_qvel[:] = qpos[r], qvel[r]
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_comVel(m, d)
            xpos[r], xmat[r], cvel[r], com[r] = d_xpos, d_xmat, d_cvel, d_com
        return kinematics_from_arrays(xpos, xmat, cvel, com, m.body_rootid, self.body_slice)

    def _fill_targets(self, qpos: np.ndarray, qvel: np.ndarray) -> _RowIndex:
        """The `DatasetScheduler`'s kinematics function: R schedule rows' target data (the
        frames' `reference_kinematics` and the features the step derives from each frame alone,
        qpos, qvel and PD targets) written to rows 0..R-1 of the environment's `TargetTable`
        slot; the scheduler's table is then the row index itself (`_RowIndex`)."""
        t, s, r = self._own_table(), self._slot, len(qpos)
        if r > t.rows:
            raise ValueError(f"{r} schedule rows do not fit the target table's {t.rows}")
        kin = self.reference_kinematics(qpos, qvel)
        t.pos[s, :r], t.rot[s, :r], t.lin[s, :r], t.ang[s, :r], t.com[s, :r] = kin.pos, kin.rot, kin.lin, kin.ang, kin.com
        t.rel[s, :r], t.features[s, :r] = kin.root_offsets(), agent_features(kin)
        t.qpos[s, :r], t.qvel[s, :r] = qpos, qvel
        if t.pd is not None:
            t.pd[s, :r] = pd_targets(self.layout, qpos, qvel, self.pd_lead_s)
        return _ROW_INDEX

    def _own_table(self) -> TargetTable:
        """The environment's `TargetTable`: one of its own, made on first use, unless a batch
        gave it a slot of the batch's."""
        if self._table is None:
            rows = max(DatasetScheduler.KINEMATICS_ROWS, self.ex.observed_offsets[-1] + 1)
            self._table = TargetTable(1, rows, len(self.bodies), self.nq, self.nv, self.nu, self.ex.actuation == "pd")
        return self._table

    def _tabled(self) -> bool:
        """The targets come from the `TargetTable` (the scheduler is the environment's own
        `DatasetScheduler`, not one swapped in by `use_scheduler`)."""
        return getattr(self.scheduler, "kinematics", None) == self._fill_targets

    def _target_kin(self, frame: TargetFrame) -> BodyKin:
        """`reference_kinematics` of one frame, for schedulers without a kinematics table."""
        # NOTE: memoized on the frame's exact bytes: the frame observed as "next" in one step is
        # the tracked one in the next step, so without it every frame's kinematics ran twice.
        key = frame.qpos.tobytes() + frame.qvel.tobytes()
        kin = self._target_kin_memo.get(key)
        if kin is None:
            kin = self.reference_kinematics(frame.qpos[None], frame.qvel[None])[0]
            if len(self._target_kin_memo) > 2 * (len(self.ex.observed_offsets) + 1):
                self._target_kin_memo.pop(next(iter(self._target_kin_memo)))  # the oldest
            self._target_kin_memo[key] = kin
        return kin

    def target_kinematics(self) -> BodyKin:
        """`BodyKin` `[1 + len(offsets)]` of the target frames now and `observed_offsets` control
        steps from now: the `DatasetScheduler`'s table rows, or each frame's kinematics (other schedulers)."""
        offsets = (0, *self.ex.observed_offsets)
        if self._tabled():
            rows = self.scheduler.kinematics_at(offsets)
            self._table.next_row[self._slot] = rows[1]
            return self._table.targets(self._slots[self._slot : self._slot + 1], rows[None])[0]
        return BodyKin.stack([self._target_kin(self.scheduler.frame(i)) for i in offsets])

    def tracking_kinematics(self) -> tuple[BodyKin, BodyKin]:
        """(the character's, the tracked target frame's) `BodyKin` now: what the reward terms of
        the last step compared (for analyses such as `morphmimic break-probe`)."""
        return character_kinematics([self])[0], self.target_kinematics()[0]

    def observe_now(self) -> np.ndarray:
        """The observation `[obs_dim]` of the state now (what a step or reset returns)."""
        return observe([self], character_kinematics([self]))[0]

    @property
    def qpos(self) -> np.ndarray:
        """The character's qpos `[nq]` (without the projectile's)."""
        return self.data.qpos[: self.nq]

    # ---- the Env contract ----

    def begins_on_reset(self, restart: bool | None = None) -> bool:
        """Whether `reset(..., restart=restart)` begins the scheduler anew (True) or resumes it:
        begun when `restart` is True, when it was not begun since `use_scheduler`, when it is
        `done`, or when it `restarts_on_reset` (absent: True, the behaviour before resuming existed)."""
        s = self.scheduler
        if restart or self._begun is not s or getattr(s, "done", False):
            return True
        return restart is None and bool(getattr(s, "restarts_on_reset", True))

    def reset(self, seed: int | None, params: np.ndarray, clip_id: str | None = None, start_s: float | None = None,
              restart: bool | None = None) -> tuple[np.ndarray, dict]:
        """Start an episode. Whether the scheduler is begun anew or resumed (`begins_on_reset`):

        - begun (the `DatasetScheduler`, whose `restarts_on_reset` is True, at every reset; any
          scheduler at the first reset after `use_scheduler`, when it is `done`, or with
          `restart=True`): `scheduler.begin` on `clip_id` (a balanced draw when None) at
          `start_s` (random when None); reactive initialization places the character off the
          tracked frame, except on the `on_frame_share` of starts that begin on it with the rule
          from the first step;
        - resumed (stitch, keyboard, video: `restarts_on_reset` False): the schedule is left
          where it is (the stitch queue's clip and time, the key script's clock, the video
          clock go on) and the character is put on its current target frame (offset 0, no
          reactive initialization, no catch-up grace); `clip_id` and `start_s` are ignored and
          no random numbers are drawn. `restart=False` resumes even a scheduler that restarts on
          reset (once it was begun and is not done)."""
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.params = self.space.validate(params).astype(np.float64)
        if self._bodies is not None:
            self._use_body(self._bodies.get(self.params))
        resumed = not self.begins_on_reset(restart)
        if resumed:
            on_frame = True
        else:
            self.scheduler.begin(self.rng, clip_id or None, start_s)
            self._begun = self.scheduler
            # Drawn only when some starts are on the frame: with none, the episode's draws are unchanged.
            on_frame = self.ex.on_frame_share > 0 and self.rng.random() < self.ex.on_frame_share
        reactive = self.ex.reactive_init and not on_frame
        offset = 0
        if reactive:
            lo, hi = self.ex.rsis_frames
            offset = int(self.rng.integers(lo, hi + 1)) * (1 if self.rng.random() < 0.5 else -1)
        start = self.scheduler.frame(offset)
        mujoco.mj_resetData(self.model, self.data)  # NOTE: a new MjData per episode cost 0.6 ms; this is the same state
        self.data.qpos[: self.nq] = start.qpos
        self.data.qvel[: self.nv] = start.qvel
        if reactive:
            r, a = self.ex.rsis_translation_m * math.sqrt(self.rng.random()), self.rng.uniform(0, 2 * math.pi)
            self.data.qpos[0:2] += r * np.array([math.cos(a), math.sin(a)])
            self.data.qvel[: self.nv] += self.rng.normal(0.0, self.ex.rsis_velocity_std, self.nv)
        self._park_projectile()
        lift_out_of_floor(self.model, self.data)
        self.k = 0
        self.previous_action = np.zeros(self.nu)
        self.grace = 0 if on_frame else self.ex.catch_up_steps
        self.last_terms: dict[str, float] = {}
        self._segment_clip = getattr(self.scheduler, "clip_id", "")
        return self.observe_now(), {"clip_id": getattr(self.scheduler, "clip_id", ""), "rsis_offset": offset,
                                                   "on_frame": on_frame, "resumed": resumed}

    def set_shape(self, shape: np.ndarray) -> np.ndarray:
        """Change the body to `shape` `[P]` now, mid-episode (`vary_shape` only; ValueError naming a
        value outside the box, or a scheduler that cannot follow a body). What carries over, and
        how the reference follows:

        - the state: the new shape's body (`ShapedBodies`, cached) is switched in and the
          character's qpos and qvel (joint angles, root pose and velocities: the same joints
          on every shape) and the simulation time are copied onto it, as are the projectile
          balls' state and whether each collides; `scale_mass`'s factor applies to it; the root
          is moved vertically so the body's lowest point is as high as before (a foot on the
          floor stays on it, whether the legs grew or shrank), then lifted out of the floor if
          another limb now reaches into it (`lift_out_of_floor`);
        - the reference: the scheduler re-reads the tracked clip on the new body
          (`body_changed`: the `DatasetScheduler` keeps the clip and its time and moves the
          retargeted clip horizontally so its root now is where the old target's root was, as
          `ImitateEnv.set_shape` does; the keyboard scheduler rebuilds its cycles on the new
          body and goes on from its state); a swapped-in scheduler without `body_changed`
          (stitch, video) is refused before anything changes;
        - the episode: its step count, the previous action, the termination grace and the
          reward's size normalization (the new body's leg ratio) go on; `params` (first in the
          observation) become the new shape.

        Returns the validated shape."""
        if self._bodies is None:
            raise ValueError("this environment's body does not vary (build it with --task.body.vary-shape)")
        new = self.space.validate(shape).astype(np.float64)
        follow = getattr(self.scheduler, "body_changed", None)
        if follow is None:
            raise ValueError(f"the {type(self.scheduler).__name__} cannot follow a body change (the frames it has "
                             "made are the old body's); change the shape under the dataset or keyboard scheduler")
        old_model, old = self.model, self.data
        qpos, qvel, t = old.qpos.copy(), old.qvel.copy(), float(old.time)
        mujoco.mj_kinematics(old_model, old)
        lowest = extent(old_model, old, 2, self.bodies)[0]
        self.params = new
        self._use_body(self._bodies.get(new))
        if self.model is old_model:
            return new
        self.data.qpos[:], self.data.qvel[:], self.data.time = qpos, qvel, t
        mujoco.mj_kinematics(self.model, self.data)
        self.data.qpos[2] += lowest - extent(self.model, self.data, 2, self.bodies)[0]
        for i, ball in enumerate(self.balls):  # in flight or parked, each ball as it was
            geom = int(old_model.body_geomadr[ball])
            self.model.body_gravcomp[ball] = old_model.body_gravcomp[ball]
            self.model.geom_contype[geom] = old_model.geom_contype[geom]
            self.model.geom_conaffinity[geom] = old_model.geom_conaffinity[geom]
            self.model.body_contype[ball] = old_model.body_contype[ball]
            self.model.body_conaffinity[ball] = old_model.body_conaffinity[ball]
        lift_out_of_floor(self.model, self.data)
        follow()
        return new

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        obs, rewards, terminated, truncated, infos = step_envs([self], np.asarray(action)[None])
        return obs[0], float(rewards[0]), bool(terminated[0]), bool(truncated[0]), infos[0]

    def _end_segment(self, tracked: bool) -> None:
        """End the current clip segment: kept with the clip time it ended at, read from the
        scheduler for a failure (its time now, inside the clip) and the clip's length for a
        tracked one (the scheduler may already be on the next clip)."""
        if self._segment_clip:
            if len(self._segments) >= MAX_UNDRAINED_SEGMENTS:  # nobody drains them (evaluation, play)
                del self._segments[0]
            motion = self._motions.get(self._segment_clip)
            length = float(motion.duration_s) if motion is not None else math.inf
            at = length if tracked and motion is not None else float(self.scheduler.status().get("clip_time_s", 0.0))
            self._segments.append((self._segment_clip, tracked, min(max(at, 0.0), length) if math.isfinite(at) else 0.0))
            self._segment_clip = ""

    def drain_segments(self) -> list[tuple[str, bool, float]]:
        """The clip segments ended since the last call, (clip id, tracked to the clip's end,
        clip time in s where it ended), for adaptive clip sampling (`sampler/clip_outcomes.py`)
        and the sampler's time bins (`sampler/time_bins.py`, which read where untracked ones
        failed): a segment runs from a start or a reschedule to the clip's end, or to the
        termination (or divergence) that cut it; an episode cut by its time limit leaves its
        segment uncounted."""
        out, self._segments = self._segments, []
        return out

    def pd_target(self, frame: TargetFrame) -> np.ndarray:
        """The PD targets `[nu]` of a zero action (`pd_target`)."""
        return pd_target(self.layout, frame, self.pd_lead_s)

    # ---- perturbations for the zero-shot robustness tests ----

    def scale_mass(self, factor: float) -> None:
        """Make every body of the character `factor` times heavier (masses and inertias, and what
        MuJoCo derives from them: `common.characters.mass`); with `vary_shape`, every body a reset
        switches to is as much heavier than compiled."""
        if not 0.05 <= factor <= 20.0:
            raise ValueError(f"mass factor {factor} must be in [0.05, 20]")
        self.mass_factor = float(factor)
        n = self.ref_model.nbody
        scale_body_mass(self.model, self.base_mass[:n], self.base_inertia[:n], factor, slice(0, n))

    def _ball_slots(self, ball: int) -> tuple[int, int, int]:
        """(qpos address, dof address, geom id) of a projectile body."""
        jnt = self.model.body_jntadr[ball]
        return int(self.model.jnt_qposadr[jnt]), int(self.model.jnt_dofadr[jnt]), int(self.model.body_geomadr[ball])

    def _park_projectile(self, which: list[int] | None = None) -> None:
        """Park balls (all by default): below the floor, at rest, weightless, colliding with nothing."""
        for i in range(len(self.balls)) if which is None else which:
            adr, dof, geom = self._ball_slots(self.balls[i])
            self.data.qpos[adr : adr + 7] = [*PARKED, 1.0, 0.0, 0.0, 0.0]
            self.data.qvel[dof : dof + 6] = 0.0
            self.model.body_gravcomp[self.balls[i]] = 1.0
            self._collides(i, False)
            self._thrown_at[i] = -1

    def _collides(self, i: int, on: bool) -> None:
        """Switch ball i's contacts on or off. NOTE: MuJoCo's broadphase filters body pairs by the
        body-level masks compiled from the geoms', so both levels are set."""
        ball = self.balls[i]
        geom = int(self.model.body_geomadr[ball])
        self.model.geom_contype[geom] = self.model.geom_conaffinity[geom] = int(on)
        self.model.body_contype[ball] = self.model.body_conaffinity[ball] = int(on)

    def _expire_projectiles(self) -> None:
        old = [i for i, k in enumerate(self._thrown_at) if k >= 0 and self.k - k >= PROJECTILE_LIFE_STEPS]
        if old:
            self._park_projectile(old)

    def throw_projectile(self, speed_mps: float = 10.0, distance_m: float = 2.0, rng: np.random.Generator | None = None) -> None:
        """Throw the next ball (`PROJECTILE`: 2 kg, 8 cm radius) at the character: it starts
        `distance_m` away horizontally from the root, in a random direction, at the root's height
        plus up to +-0.3 m, and flies at `speed_mps` aimed at where the centre of mass will be (the
        root's velocity held over the flight), under gravity. A ball is
        parked again 1 s after its throw; `PROJECTILES` balls are thrown in turn."""
        if not self.balls:
            raise ValueError("this environment has no projectile: build it with --task.executor.projectile")
        if not (0.0 < speed_mps <= 100.0 and 0.0 < distance_m <= 20.0):
            raise ValueError(f"projectile speed {speed_mps} m/s must be in (0, 100] and distance {distance_m} m in (0, 20]")
        rng = rng or self.rng
        i = self._next_ball
        self._next_ball = (i + 1) % len(self.balls)
        root = self.qpos[0:3].copy()
        a = rng.uniform(0.0, 2.0 * math.pi)
        start = root + np.array([distance_m * math.cos(a), distance_m * math.sin(a), rng.uniform(-0.3, 0.3)])
        start[2] = max(start[2], PROJECTILE["radius_m"] + 0.05)
        # NOTE: aimed where the centre of mass will be when the ball arrives (the root's current
        # velocity held): the body's largest target, wherever a tumbling character's root is.
        aim = self.data.subtree_com[1] + self.data.qvel[0:3] * (distance_m / speed_mps)
        direction = aim - start
        direction /= np.linalg.norm(direction)
        adr, dof, geom = self._ball_slots(self.balls[i])
        self.data.qpos[adr : adr + 7] = [*start, 1.0, 0.0, 0.0, 0.0]
        self.data.qvel[dof : dof + 3] = speed_mps * direction
        self.data.qvel[dof + 3 : dof + 6] = 0.0
        self.model.body_gravcomp[self.balls[i]] = 0.0
        self._collides(i, True)
        self._thrown_at[i] = self.k


# ---- the step over a batch of environments (`ExecutorEnv.step` is the batch of one) ----


def _stack(arrays: Sequence[np.ndarray]) -> np.ndarray:
    """`np.stack(arrays)`; a view of a single array (the single environment's batch of one)."""
    return arrays[0][None] if len(arrays) == 1 else np.stack(arrays)


def character_kinematics(envs: Sequence[ExecutorEnv]) -> BodyKin:
    """`BodyKin` `[N]` of each environment's character now.

    NOTE: after mj_step the body poses are those before the last integration; they are
    recomputed (kinematics and velocities only, no contacts) so state and targets are in step."""
    for env in envs:
        mujoco.mj_kinematics(env.model, env.data)
        mujoco.mj_comPos(env.model, env.data)
        mujoco.mj_comVel(env.model, env.data)
    views = [env.views(env.data, KINEMATICS_ARRAYS) for env in envs]
    return kinematics_from_arrays(*(_stack(arrays) for arrays in zip(*views)), envs[0].model.body_rootid, envs[0].body_slice)


KINEMATICS_ARRAYS = ("xpos", "xmat", "cvel", "subtree_com")
"""The MjData arrays `kinematics_from_arrays` reads."""
STEP_ARRAYS = ("warning.number", "ctrl", "qpos", "qvel")
"""The MjData arrays a step reads and writes besides those."""


@dataclass(frozen=True)
class Targets:
    """What a step reads of M environments' target frames: the tracked frame's (now: `com`
    `[M, 3]`, body positions `pos` `[M, B, 3]`, `rel` `[M, B - 1, 3]`
    (`BodyKin.root_offsets`), `qpos` `[M, nq]`, `qvel` `[M, nv]`) and the observed frames'
    (`ExecutorConfig.observed_offsets`, K of them, control steps ahead: o(X~) `features`
    `[M, K, F]`, root positions `root_pos` `[M, K, 3]` and rotations `root_rot` `[M, K, 3, 3]`)."""

    com: np.ndarray
    pos: np.ndarray
    rel: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    features: np.ndarray
    root_pos: np.ndarray
    root_rot: np.ndarray


def target_rows(envs: Sequence[ExecutorEnv], slots: np.ndarray | None) -> Targets:
    """The environments' `Targets` now. With `slots` (the environments share a `TargetTable`,
    these are their slots, and each is `_tabled`): each scheduler looks its rows up
    (`kinematics_at`), the rows one step ahead become the next PD targets' (`next_row`), and
    every array is one gather from the table. Else computed from each scheduler's frames."""
    offsets = (0, *envs[0].ex.observed_offsets)
    if slots is not None:
        table = envs[0]._table
        rows = np.array([env.scheduler.kinematics_at(offsets) for env in envs])
        table.next_row[slots] = rows[:, 1]
        now = (slots, rows[:, 0])
        ahead = (slots[:, None], rows[:, 1:])
        return Targets(table.com[now], table.pos[now], table.rel[now], table.qpos[now], table.qvel[now],
                       table.features[ahead], table.pos[ahead + (0,)], table.rot[ahead + (0,)])
    kin = BodyKin.stack([env.target_kinematics() for env in envs])
    frames = [env.scheduler.frame(0) for env in envs]
    now, ahead = kin[:, 0], kin[:, 1:]
    return Targets(now.com, now.pos, now.root_offsets(), _stack([f.qpos for f in frames]),
                   _stack([f.qvel for f in frames]), agent_features(ahead), ahead.pos[..., 0, :], ahead.rot[..., 0, :, :])


def table_slots(envs: Sequence[ExecutorEnv]) -> np.ndarray | None:
    """The environments' slots in the `TargetTable` they share, or None (`target_rows`)."""
    table = envs[0]._own_table()
    if all(env._table is table and env._tabled() for env in envs):
        return np.fromiter((env._slot for env in envs), np.intp, len(envs))
    return None


def observe(envs: Sequence[ExecutorEnv], actual: BodyKin, targets: Targets | None = None) -> np.ndarray:
    """Observations `[N, obs_dim]` of the environments (`observation`) from their characters'
    `BodyKin` `[N]` and their `Targets` (looked up when None)."""
    if targets is None:
        targets = target_rows(envs, table_slots(envs))
    params = _stack([env.params for env in envs])
    obs = observation_of(actual, targets.features, targets.root_pos, targets.root_rot, params)
    if envs[0].ex.previous_action_obs:
        obs = np.concatenate([obs, _stack([env.previous_action for env in envs]).astype(np.float32)], axis=-1)
    return obs


def _mean_length(d: np.ndarray) -> np.ndarray:
    """`np.mean(np.linalg.norm(d, axis=-1), axis=-1)` of real `[..., B, 3]`, by the ufuncs those
    two call (the same sum of squares, square root, sum and division, so bit for bit theirs)
    without their Python wrappers, which cost more than the arithmetic here."""
    return np.add.reduce(np.sqrt(np.add.reduce(d * d, axis=-1)), axis=-1) / d.shape[-2]


def tracking_errors(envs: Sequence[ExecutorEnv], q: np.ndarray, actual: BodyKin, target: Targets,
                    qpos_before: Sequence[np.ndarray] | None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Each environment's five reward terms' errors `[N, 5]` (UniCon eq. 5's kernels' arguments,
    in `rewards.TERMS` order; with `vary_shape` and `reward_normalization` the position terms'
    divided by the body's size, `rewards.size_normalized_errors`) and position errors in metres
    (`joint_error_m`, `body_error_m`, `[N]` each), from the characters' qpos `q` `[N, nq]`
    (C-ordered) and `BodyKin` `[N]` and the tracked frames' (`Targets`); `qpos_before` (each
    environment's joint angles a control step ago, or None) makes the joint-velocity term
    compare the step's mean velocity (`ExecutorConfig.joint_velocity = "step_mean"`)."""
    first = envs[0]
    qr, qvel_ref = target.qpos, target.qvel
    qvel = np.stack([env.views(env.data, STEP_ARRAYS)[3][: env.nv] for env in envs])  # a copy: step_mean overwrites rows
    for i, before in enumerate(qpos_before or ()):
        mujoco.mj_differentiatePos(first.ref_model, qvel[i], first.dt, before, q[i])
    lay = first.layout
    rel, rel_ref = rw.yaw_aligned(actual.root_offsets(), q[:, 3:7], qr[:, 3:7]), target.rel
    errors = np.empty((len(q), len(rw.TERMS)))
    errors[:, 0] = rw.com_errors(actual.com, target.com)
    errors[:, 1] = rw.root_rotation_errors(q[:, 3:7], qr[:, 3:7])
    errors[:, 2] = rw.joint_position_errors(rel, rel_ref)
    errors[:, 3] = rw.joint_rotation_errors(q[:, lay.ball_qpos], qr[:, lay.ball_qpos], q[:, lay.hinge_qpos], qr[:, lay.hinge_qpos])
    errors[:, 4] = rw.joint_velocity_errors(qvel[:, 6:], qvel_ref[:, 6:])
    if first.body is not None and first.ex.reward_normalization:  # vary_shape: position terms by body size
        errors = rw.size_normalized_errors(errors, np.array([env.leg_ratio for env in envs]))
    positions = {"joint_error_m": _mean_length(rel - rel_ref), "body_error_m": _mean_length(actual.pos - target.pos)}
    return errors, positions


def step_envs(envs: Sequence[ExecutorEnv], actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict]]:
    """One control step of every environment of `envs` (one configuration) with `actions`
    `[N, nu]`: observations `[N, obs_dim]`, rewards `[N]`, terminated `[N]`, truncated `[N]` and
    one info dict each (see `ExecutorEnv`). Actuation, kinematics features, reward terms,
    termination and observations are array operations over the N environments, each state's
    arithmetic the same as alone (so environment i's results are those of stepping it alone,
    bit for bit); physics (`mj_step`; `step_physics`'s divergence check runs over all N), the
    scheduler's advance (with the environment's own generator) and the episode bookkeeping run
    per environment."""
    first = envs[0]
    ex, n = first.ex, len(envs)
    table = first._table
    slots = table_slots(envs)
    a = np.asarray(actions, dtype=np.float64)
    if not np.isfinite(a).all():  # checked first: nan_to_num on every step cost 30 us
        a = np.nan_to_num(a)
    applied = np.clip(a, -rw.ACTION_BOUNDS[ex.actuation], rw.ACTION_BOUNDS[ex.actuation])
    if ex.actuation == "torque":
        ctrl = applied
    else:
        if slots is not None:  # the next frames' PD targets, computed once per schedule row
            zero = table.pd[slots, table.next_row[slots]]
        else:
            nxt = [env.scheduler.frame(1) for env in envs]
            zero = pd_targets(first.layout, _stack([f.qpos for f in nxt]), _stack([f.qvel for f in nxt]), first.pd_lead_s)
        ctrl = zero + ex.pd_action_scale * applied
    terminated, truncated = [False] * n, [False] * n
    infos: list[dict] = [{} for _ in range(n)]
    step_mean = ex.joint_velocity == "step_mean"
    befores_all = [env.qpos.copy() for env in envs] if step_mean else None
    # Physics of every environment, then `step_physics`'s divergence check over all N at once
    # (the divergence warnings' count changed, or a non-finite qpos): one array op instead of
    # four per environment.
    views = [env.views(env.data, STEP_ARRAYS) for env in envs]
    warned = np.array([v[0] for v in views])
    substeps = first.cfg.substeps
    for env, v, c in zip(envs, views, ctrl):
        v[1][:] = c
        mujoco.mj_step(env.model, env.data, nstep=substeps)
    warned -= np.array([v[0] for v in views])
    qpos = np.array([v[2] for v in views])
    warned = warned[:, _DIVERGENCE_WARNINGS]
    if warned.any() or not np.isfinite(qpos).all():  # else no environment diverged: two calls in the common case
        diverged = ((warned.sum(axis=1) != 0) | ~np.isfinite(qpos).all(axis=1)).tolist()
    else:
        diverged = [False] * n
    live, befores, rescheduled = [], [], []
    for i, env in enumerate(envs):
        env.k += 1
        if env.balls:
            env._expire_projectiles()
        if diverged[i]:  # a zero observation and reward (`diverged_step`), filled in below
            env._end_segment(False)
            _, _, terminated[i], truncated[i], infos[i] = diverged_step(first.obs_dim, ended_by="divergence")
            continue
        moved = env.scheduler.advance(env.rng, qpos[i, : env.nq])  # a row of a copy: the character's qpos now
        if moved:
            env.grace = env.k + ex.catch_up_steps
            env._end_segment(True)
            env._segment_clip = getattr(env.scheduler, "clip_id", "")
        live.append(i)
        rescheduled.append(moved)
    every = len(live) == n  # the common case: nothing diverged, so no rows to pick or fill in
    if every:
        running, on, q = envs, slots, (qpos if qpos.shape[1] == first.nq else qpos[:, : first.nq].copy())
    else:
        running, on, q = [envs[i] for i in live], None if slots is None else slots[live], qpos[live, : first.nq]
    if not live:
        return np.zeros((n, first.obs_dim), np.float32), np.zeros(n), np.array(terminated), np.array(truncated), infos
    befores = None if befores_all is None else [befores_all[i] for i in live]
    actual = character_kinematics(running)
    targets = target_rows(running, on)
    errors, positions = tracking_errors(running, q, actual, targets, befores)
    terms = rw.term_values(errors, ex.reward_scales)
    step_rewards = rw.weighted_sums(terms, ex.reward_weights)
    if ex.action_rate_weight > 0.0:
        penalties = rw.action_rate_penalties(applied, _stack([env.previous_action for env in envs]), ex.action_rate_weight)
        step_rewards = step_rewards - (penalties if every else penalties[live])
    for env, act in zip(envs, applied):  # what the next observation shows and the next penalty compares with
        env.previous_action = act
    ends = rw.terminations(terms, ex.reward_weights, ex.termination, ex.alpha, ex.terminate_on)
    if every:
        obs, rewards = observe(running, actual, targets), step_rewards
    else:
        obs, rewards = np.zeros((n, first.obs_dim), np.float32), np.zeros(n)
        obs[live], rewards[live] = observe(running, actual, targets), step_rewards
    # NOTE: Python floats by `tolist` (one call per array), not float() of each numpy scalar
    term_rows, dists = terms.tolist(), {k: v.tolist() for k, v in positions.items()}
    for j, (i, env) in enumerate(zip(live, running)):
        ended_by = ends[j]
        if ended_by is None and env.k < env.grace and ex.catch_up_ends == "on_track":
            env.grace = env.k  # caught up: the rule applies from the next step
        term = ended_by is not None and env.k > env.grace
        trunc = not term and (env.k >= env.cfg.episode_steps or env.scheduler.done)
        if term or (trunc and env.scheduler.done):  # a time limit says nothing of the clip
            env._end_segment(not term)
        env.last_terms = dict(zip(rw.TERMS, term_rows[j]))
        terminated[i], truncated[i] = term, trunc
        infos[i] = {"diverged": False, "terms": env.last_terms, "ended_by": ended_by if term else None,
                    "rescheduled": rescheduled[j], **{k: v[j] for k, v in dists.items()}, **env.scheduler.status()}
    return obs, rewards, np.array(terminated), np.array(truncated), infos
