#!/usr/bin/env bash
# Resume the training runs that did not finish in one session (see README.md beside this file).
# Each run continues from runs/<name> if it has a checkpoint there, else from the checkpoint kept
# here; a run listed in FRESH may start from nothing when neither exists (any other run stops
# with an error rather than silently start over).
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
  [manta-nocourse]="--preset manta --task.imitate.no-observe-course --mode serial"
  [executor-torque]="--preset executor --mode serial"
  [executor-pd-cont]="--preset executor-pd --mode serial"
)
FRESH=(manta-course)
names=("$@")
[ ${#names[@]} -eq 0 ] && names=(qabl-nonorm qabl-fixedshape manta-course executor-torque executor-pd-cont)
declare -A FROM=()
for name in "${names[@]}"; do  # every name checked before anything starts
  [ -n "${ARGS[$name]+x}" ] || { echo "resume.sh: unknown run '$name'; choose one of ${!ARGS[*]}" >&2; exit 2; }
  if compgen -G "runs/$name/ckpt/*/state.pt" >/dev/null; then FROM[$name]=auto
  elif [ -f "$HERE/$name/state.pt" ]; then FROM[$name]="$HERE/$name"
  elif [[ " ${FRESH[*]} " == *" $name "* ]]; then FROM[$name]=never
  else echo "resume.sh: run '$name' has no checkpoint in runs/$name/ckpt nor $HERE/$name/state.pt" >&2; exit 2
  fi
done
mkdir -p runs
for name in "${names[@]}"; do
  # shellcheck disable=SC2086
  nohup nice -n 5 python -m learner.main ${ARGS[$name]} --name "$name" --resume "${FROM[$name]}" --quiet >> "runs/$name.out" 2>&1 &
  echo "resumed $name from ${FROM[$name]} (pid $!)"
done
