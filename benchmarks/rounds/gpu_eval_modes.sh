#!/usr/bin/env bash
# On one GPU: one checkpoint evaluated in test mode under each step execution (shipped: compiled and captured; compiled
# only; eager), one eval line each. The three must agree within the sampling noise of the test episodes; a gap points
# at the step's graphs (benchmarks/diagnostics/check_step_graph.py then finds the step that differs).
# Usage: bash benchmarks/rounds/gpu_eval_modes.sh TASK CHECKPOINT [NUM_ENVS]
set -uo pipefail
task=$1; checkpoint=$2; envs=${3:-}
for mode in shipped "+task.sim.captureStep=False" "+task.sim.captureStep=False +task.sim.compileStep=False"; do
  extra=""; [ "$mode" != shipped ] && extra=$mode
  # shellcheck disable=SC2086  # $extra holds zero, one or two overrides
  output=$(python3 train.py task="$task" test=True checkpoint="$checkpoint" headless=True ${envs:+num_envs=$envs} \
           $extra 2>&1)
  line=$(grep '^\[eval\] {' <<< "$output")
  # no eval line: the run failed, and its last lines say why
  echo "$mode: ${line:-no eval line; the run ended with:$'\n'$(tail -n 15 <<< "$output")}"
done
