#!/usr/bin/env bash
# Resume the training runs that did not finish in one session (see README.md beside this file).
# Each run continues from runs/<name> if it has a checkpoint there, else from the checkpoint kept
# here, else (a run listed in FORK) from the shared checkpoint it was forked from; a run listed in
# FRESH may start from nothing when none exists (any other run stops with an error rather than
# silently start over).
# A run is either `learner.main ...` or `learner.curriculum --stages ... -- ...` (the curriculum
# skips the stages its checkpoint has passed; a checkpoint kept here is a fork it counts from).
# Usage: bash learner/pretrained/in-progress/resume.sh [--dry-run] [name ...]   (default: the first run of ORDER)
#   --dry-run: print each run's command (one line each) instead of starting it
# One run takes the whole machine in local mode (two rollout actors and the learner on their own
# cores: lb5-mb128, now learner/pretrained/lower_biped-smooth, made 2,350 steps/s so, against 800
# in serial mode beside another serial run);
# several runs named at once each run in serial mode (one process, no Ray) and share the cores.
set -euo pipefail
cd "$(dirname "$0")/../../.."
HERE=learner/pretrained/in-progress
declare -A ARGS=(
  [manta-course]="learner.main --preset manta"
  [manta-nocourse]="learner.main --preset manta --task.imitate.no-observe-course"
  [executor-torque]="learner.main --preset executor"
  [xmix-50]="learner.main --preset executor-pd --ppo.gamma 0.99"
)
ORDER=(xmix-50 executor-torque manta-course)  # what to resume first
FRESH=(manta-course)
# FORK: a run that starts from a shared checkpoint, when it has none of its own (the rotor-inertia
# arms xank-* forked the shipped executor, 2026-12-05, the lower biped's ablation arms lbabl-fork).
declare -A FORK=([xmix-50]=learner/pretrained/executor)  # its iteration 1816, shipped in session 42
DRY=0
if [ "${1:-}" = "--dry-run" ]; then DRY=1; shift; fi
names=("$@")
[ ${#names[@]} -eq 0 ] && names=("${ORDER[0]}")
MODE=local
[ ${#names[@]} -gt 1 ] && MODE=serial
declare -A FROM=()
for name in "${names[@]}"; do  # every name checked before anything starts
  [ -n "${ARGS[$name]+x}" ] || { echo "resume.sh: unknown run '$name'; choose one of ${!ARGS[*]}" >&2; exit 2; }
  if compgen -G "runs/$name/ckpt/*/state.pt" >/dev/null; then FROM[$name]=auto
  elif [ -f "$HERE/$name/state.pt" ]; then FROM[$name]="$HERE/$name"
  elif [ -n "${FORK[$name]+x}" ] && [ -f "${FORK[$name]}/state.pt" ]; then FROM[$name]="${FORK[$name]}"
  elif [[ " ${FRESH[*]} " == *" $name "* ]]; then FROM[$name]=never
  else echo "resume.sh: run '$name' has no checkpoint in runs/$name/ckpt nor $HERE/$name/state.pt${FORK[$name]+ nor its fork ${FORK[$name]}/state.pt}" >&2; exit 2
  fi
done
if [ $DRY = 1 ]; then
  for name in "${names[@]}"; do echo "python -m ${ARGS[$name]} --mode $MODE --name $name --resume ${FROM[$name]} --quiet"; done
  exit 0
fi
mkdir -p runs
for name in "${names[@]}"; do
  # shellcheck disable=SC2086
  nohup nice -n 5 python -m ${ARGS[$name]} --mode "$MODE" --name "$name" --resume "${FROM[$name]}" --quiet >> "runs/$name.out" 2>&1 &
  echo "resumed $name from ${FROM[$name]} in $MODE mode (pid $!)"
done
