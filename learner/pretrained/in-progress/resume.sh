#!/usr/bin/env bash
# Resume the training runs that did not finish in one session (see README.md beside this file).
# Each run continues from runs/<name> if that directory survived, else from the checkpoint kept here.
# Usage: bash learner/pretrained/in-progress/resume.sh [name ...]   (default: every run listed below)
set -euo pipefail
cd "$(dirname "$0")/../../.."
HERE=learner/pretrained/in-progress
declare -A ARGS=(
  [qabl-adaptive]="--preset quadruped --ppo.gamma 0.99 --total-env-steps 7300000 --mode serial"
  [qabl-uniform]="--preset quadruped-uniform --ppo.gamma 0.99 --total-env-steps 7300000 --mode serial"
  [qabl-nonorm]="--preset quadruped-nonorm --ppo.gamma 0.99 --total-env-steps 7300000 --mode serial"
  [qabl-fixedshape]="--preset quadruped-fixedshape --ppo.gamma 0.99 --total-env-steps 7300000 --mode serial"
  [manta-course]="--preset manta --mode serial"
  [executor-torque]="--preset executor --mode serial"
  [executor-pd-cont]="--preset executor-pd --mode serial"
)
names=("$@")
[ ${#names[@]} -eq 0 ] && names=(qabl-nonorm qabl-fixedshape manta-course executor-torque executor-pd-cont)
mkdir -p runs
for name in "${names[@]}"; do
  [ -n "${ARGS[$name]+x}" ] || { echo "resume.sh: unknown run '$name'; choose one of ${!ARGS[*]}" >&2; exit 2; }
  if ls "runs/$name/ckpt" >/dev/null 2>&1; then from=auto
  elif [ -f "$HERE/$name/state.pt" ]; then from="$HERE/$name"
  else from=never; fi  # a run not started yet
  # shellcheck disable=SC2086
  nohup nice -n 5 python -m learner.main ${ARGS[$name]} --name "$name" --resume "$from" --quiet >> "runs/$name.out" 2>&1 &
  echo "resumed $name from $from (pid $!)"
done
