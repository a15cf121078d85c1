"""`morphmimic distill`: start a torque executor from a PD executor (DAgger), then train it on.

    morphmimic distill --teacher learner/pretrained/executor --out runs/executor-distilled
    morphmimic train --preset executor --name executor-torque --resume runs/executor-distilled/ckpt/00000900

UniCon 2020 (METHOD.md B) trains its torque executor from scratch; on this 2-core machine no
torque run survived UniCon's per-term rule past its 30-step wait in 3 M steps
(`learner/pretrained/executor/README-torque-2.8M.md`), while the PD executor tracks some clips.
A torque policy can first learn what the PD executor does: at every state it visits, the
teacher's action gives a PD target (the next target frame + `pd_action_scale` x action, as
`ExecutorEnv.step`) and MuJoCo's PD actuators give a torque there (`mj_step` on the PD model
from the same state in a copy, the actuator force averaged over the control step's substeps,
within the PD's torque limits). The student's label is that torque over the torque model's
effort factors, plus what the torque model's passive damping takes away, clipped to [-1, 1].
NOTE: it is an approximation, measured as such. MuJoCo's implicitfast integrator applies the
PD's damping implicitly, so the explicit force is not the impulse the PD gives, and a torque
held for the control step does not reproduce the PD's step (on 4 states of the humanoid the
joint velocities after one held label step were further from the PD's than after no torque);
inverse dynamics per substep (`mjENBL_INVDISCRETE`) reproduces it only without contacts, and
its average held for the step does not. What counts is the closed loop: acting with the labels
in the training distribution (reactive initialization, UniCon's rule after the 30-step wait),
episodes last 40.3 control steps against the PD executor's own 44.5, and the distilled student
reaches 41.1 after three rounds, where torque training from scratch sat at 35.6 after 3 M steps.
Dataset Aggregation
(Ross, Gordon & Bagnell 2011): the first round acts with the labels themselves, every later
round with the student (its mean action), and the student fits all rounds' states by least
squares on its mean. The observation is the same in both actuations, so the student starts
from the teacher's observation normalizer and its value net starts as the teacher's.

The output is a training checkpoint of the torque task (the teacher's task with
`actuation="torque"`) that `python -m learner.main --resume` continues; its step count is the
teacher's plus the distillation's, so a budget counts every transition.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import mujoco
import numpy as np
import torch

from common.config_limits import SEED, Limit, above, at_least, check_limits, validated
from common.policy import anneal_log_std
from common.tasks.executor.env import ExecutorEnv, pd_lead_s, pd_target
from learner import checkpoint
from learner.cli_options import parse_options, refuse
from learner.learner import Learner


class TorqueLabeler:
    """The PD teacher's torque at a torque env's state, as the student's action (module docstring)."""

    def __init__(self, env, pd_model: mujoco.MjModel, pd_action_scale: float):
        self.env = env
        self.pd_model = pd_model
        self.pd_data = mujoco.MjData(pd_model)
        self.scale = pd_action_scale
        self.lead_s = pd_lead_s(pd_model) if env.ex.pd_velocity_target else None
        act_dofs = [int(pd_model.jnt_dofadr[pd_model.actuator_trnid[a, 0]]) for a in range(pd_model.nu)]
        # one actuator per DOF in joint order: a ball joint's three actuators drive its three DOFs
        self.dofs = np.array([d + (act_dofs[:a].count(d)) for a, d in enumerate(act_dofs)])
        self.damping = env.model.dof_damping[self.dofs].copy()
        self.efforts = env.efforts.copy()
        self.substeps = env.cfg.substeps

    def label(self, teacher_action: np.ndarray) -> np.ndarray:
        """`[nu]` torque action in [-1, 1] for the env's current state: the PD's force averaged
        over the control step's substeps, run from this state in a copy (module docstring: an
        approximation; the first substep's force alone, held for the step, gave training
        episodes of 34.9 control steps against 40.3 with the average)."""
        env, d = self.env, self.pd_data
        d.qpos[:] = env.data.qpos[: self.pd_model.nq]
        d.qvel[:] = env.data.qvel[: self.pd_model.nv]
        d.time = env.data.time
        target = pd_target(env.layout, env.scheduler.frame(1), self.lead_s)
        d.ctrl[:] = target + self.scale * np.clip(teacher_action, -3.0, 3.0)
        total = np.zeros(self.pd_model.nu)
        for _ in range(self.substeps):
            qvel = d.qvel[self.dofs].copy()
            mujoco.mj_step(self.pd_model, d)
            total += d.actuator_force + self.damping * qvel
        return np.clip(total / (self.substeps * self.efforts), -1.0, 1.0)


def load_teacher(teacher_dir: str | Path):
    """The PD executor checkpoint at `teacher_dir` (`checkpoint.Loaded`); ValueError naming it if
    it is missing, unreadable, or not a PD executor."""
    try:
        loaded = checkpoint.load_trained(teacher_dir)
    except SystemExit as exc:  # load_trained's one-line message for a missing or unreadable checkpoint
        raise ValueError(f"--teacher {teacher_dir}: {str(exc.code).replace('--checkpoint ', '')}") from None
    task = loaded.cfg.task
    if task.name != "executor" or task.executor.actuation != "pd":
        raise ValueError(f"--teacher {teacher_dir}: a PD executor checkpoint is needed (task {task.name!r}, "
                         f"actuation {task.executor.actuation if task.name == 'executor' else None!r})")
    return loaded


def distill(loaded, out: str | Path, rounds: int = 6, steps_per_round: int = 20_000,
            epochs: int = 20, lr: float = 1e-3, seed: int = 0, log=print) -> Path:
    """DAgger from the PD executor checkpoint `loaded` (`load_teacher`) into a torque executor
    checkpoint at `out` (`out/ckpt/<iteration>/state.pt`); returns the checkpoint directory."""
    cfg = loaded.cfg
    student_task = dataclasses.replace(cfg.task, executor=dataclasses.replace(cfg.task.executor, actuation="torque"))
    student_cfg = dataclasses.replace(cfg, task=student_task, name=Path(out).name, seed=seed, resume="auto")
    rng = np.random.default_rng(seed)
    env = ExecutorEnv(student_task, seed=seed)
    pd_model = ExecutorEnv(cfg.task, seed=seed).model
    labeler = TorqueLabeler(env, pd_model, cfg.task.executor.pd_action_scale)
    teacher = checkpoint.make_policy(loaded, env.obs_dim, env.act_dim)
    learner = Learner(student_cfg)  # seeds torch with `seed`: the student's initial weights
    student = learner.policy
    student.normalizer.load_state_dict(teacher.normalizer.state_dict())
    # NOTE: checkpoints from before the value net's return statistics have none: keep (0, 1), as
    # `Learner.load_state_dict` does.
    learner.value.load_state_dict({**{k: v for k, v in learner.value.state_dict().items() if k.startswith("target_")},
                                   **loaded.state["value"]})
    optimizer = torch.optim.Adam(student.mean_net.parameters(), lr=lr)

    obs_all: list[np.ndarray] = []
    labels_all: list[np.ndarray] = []
    obs, _ = env.reset(int(rng.integers(2**31)), env.space.default_array)
    steps, length, ret = 0, 0, 0.0
    for r in range(rounds):
        t0, lengths, returns = time.monotonic(), [], []
        obs_r, lab_r = np.zeros((steps_per_round, env.obs_dim), np.float32), np.zeros((steps_per_round, env.act_dim), np.float32)
        for i in range(steps_per_round):
            with torch.no_grad():
                t_act = teacher.act(obs[None], deterministic=True)[0][0]
            u = labeler.label(t_act)
            obs_r[i], lab_r[i] = obs, u
            act = u if r == 0 else student.act(obs[None], deterministic=True)[0][0]
            obs, reward, terminated, truncated, _ = env.step(act)
            length, ret = length + 1, ret + reward
            if terminated or truncated:
                lengths.append(length)
                returns.append(ret)
                length, ret = 0, 0.0
                obs, _ = env.reset(int(rng.integers(2**31)), env.space.default_array)
        steps += steps_per_round
        obs_all.append(obs_r)
        labels_all.append(lab_r)
        who = "labels" if r == 0 else "student"
        log(f"[distill] round {r + 1}/{rounds}: {steps_per_round:,d} steps acted by the {who}, "
            f"{len(lengths)} episodes, mean length {np.mean(lengths) if lengths else float('nan'):.1f} control steps, "
            f"mean return {np.mean(returns) if returns else float('nan'):.2f} ({time.monotonic() - t0:.0f} s)")
        x = torch.as_tensor(np.concatenate(obs_all))
        y = torch.as_tensor(np.concatenate(labels_all))
        with torch.no_grad():
            xn = student.normalizer(x)
        for _ in range(epochs):
            order = torch.randperm(len(x))
            for start in range(0, len(x), 512):
                idx = order[start : start + 512]
                loss = (student.mean_net(xn[idx]) - y[idx]).square().mean()
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
        with torch.no_grad():
            fit = float((student.mean_net(xn) - y).square().mean())
        log(f"[distill] round {r + 1}/{rounds}: fitted {len(x):,d} states, mean squared error {fit:.4f} "
            f"(label variance {float(y.var(0).mean()):.4f})")
    learner.env_steps = int(loaded.state.get("env_steps", 0)) + steps
    learner.iteration = int(loaded.state.get("iteration", 0))
    learner.policy_version = learner.iteration
    learner.episodes = int(loaded.state.get("episodes", 0))
    learner.train_seconds = float(loaded.state.get("train_seconds", float("nan")))
    anneal_log_std(student, student_cfg.policy, learner.env_steps)  # where the variance controller stands
    return checkpoint.save(Path(out) / "ckpt", learner.iteration, learner.state_dict(), keep=1)


PROG = "morphmimic distill"


@validated
@dataclass
class DistillOptions:
    teacher: str
    """A PD executor checkpoint (run dir, ckpt dir or learner/pretrained/<name>)."""
    out: str
    """Run directory to write (its ckpt/<iteration>/state.pt)."""
    rounds: int = 6
    """DAgger rounds (the first acts with the labels)."""
    steps: int = 20_000
    """Control steps collected per round."""
    epochs: int = 20
    """Passes over all rounds' states after each round."""
    lr: float = 1e-3
    """Adam step size of the fit."""
    seed: int = 0
    """Seed of the student's weights, resets and fit."""

    LIMITS: ClassVar[dict[str, Limit]] = {"rounds": at_least(1), "steps": at_least(1), "epochs": at_least(1),
                                          "lr": above(0), "seed": SEED}
    FLAG_PREFIX: ClassVar[str] = ""

    def validate(self) -> None:
        check_limits(self)


def main(argv: list[str]) -> int:
    args = parse_options(DistillOptions, argv, prog=PROG, description=__doc__)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        refuse(PROG, f"--out {out} is a file; give a new directory")
    if checkpoint.list_checkpoints(out / "ckpt"):
        refuse(PROG, f"--out {out} already holds checkpoints; give a new directory")
    try:
        loaded = load_teacher(args.teacher)
    except ValueError as exc:
        refuse(PROG, str(exc))
    path = distill(loaded, out, args.rounds, args.steps, args.epochs, args.lr, args.seed)
    print(f"[distill] wrote {path}; continue with: morphmimic train --preset executor --name <name> --resume {path}")
    return 0
