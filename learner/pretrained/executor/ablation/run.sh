#!/usr/bin/env bash
# Item 6 of issue 20: arms forked from executor-pd4 iteration 200 (1,638,400 steps), each to 2,621,440 steps
# (the baseline arm is executor-pd4's own iteration 320 on the same budget).
# The PD arms ran before the preset switched its PD to a target velocity (2026-12-04): the flag keeps them as they were.
cd /work/main && . .venv/bin/activate
FORK=runs/executor-pd4/ckpt/00000200
T=2621440
python -m learner.main --preset executor --name abl-torque --resume $FORK --total-env-steps $T > runs/abl-torque.out 2>&1
python -m learner.main --preset executor-pd --task.executor.no-pd-velocity-target --name abl-noterm --resume $FORK --total-env-steps $T --task.executor.termination sum > runs/abl-noterm.out 2>&1
python -m learner.main --preset executor-pd --task.executor.no-pd-velocity-target --name abl-uniform --resume $FORK --total-env-steps $T --task.executor.clip-draws uniform > runs/abl-uniform.out 2>&1
python -m learner.main --preset executor-pd --task.executor.no-pd-velocity-target --name abl-norsis --resume $FORK --total-env-steps $T --task.executor.no-reactive-init > runs/abl-norsis.out 2>&1
echo done > runs/ablation.done
