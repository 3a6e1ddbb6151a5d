#!/usr/bin/env bash
# On a GPU machine: does a run signalled by `timeout` (SIGTERM to the process and its whole group) keep its work?
# Trains TASK with the shipped defaults, sends SIGTERM after AFTER_S seconds, and reports the exit status, the stop
# line, the interrupted checkpoint and summary.json (expected at any time after the first iteration; before it, the
# one-line "no checkpoint exists yet" and status 143).
# Usage: bash benchmarks/rounds/gpu_signal.sh TASK AFTER_S OUTDIR [overrides...]
# CACHE=cold empties Warp's kernel cache and the compiled step's Inductor/Triton caches first (each lane should have
# its own WARP_CACHE_PATH / TORCHINDUCTOR_CACHE_DIR / TRITON_CACHE_DIR when several run at once).
set -uo pipefail
task=$1; after=$2; out=$3; shift 3
mkdir -p "$out"
log="$out/$task.sig$after.log"
if [ "${CACHE:-warm}" = cold ]; then
  rm -rf "${WARP_CACHE_PATH:-$HOME/.cache/warp}" "${TORCHINDUCTOR_CACHE_DIR:-/tmp/torchinductor_$(whoami)}" \
         "${TRITON_CACHE_DIR:-$HOME/.triton/cache}"
fi
timeout --preserve-status -s TERM "$after" python3 train.py task="$task" headless=True runs_dir="$out/runs.$task.$after" \
  "$@" > "$log" 2>&1
rc=$?
run_dir=$(ls -d "$out/runs.$task.$after/$task"/*/ 2>/dev/null | head -1)
ckpt=$(ls "$run_dir"/model_*_interrupted.pt 2>/dev/null | head -1)
summary=no; [ -n "$run_dir" ] && [ -f "$run_dir/summary.json" ] && summary=yes
last_it=$(grep -o '^\[it *[0-9]*' "$log" | tail -1 | tr -d '[it ')
echo "$task SIGTERM at ${after}s: rc=$rc last_iteration=${last_it:-none} interrupted_ckpt=$(basename "${ckpt:-none}") summary=$summary | $(grep -E '^\[train\] (stopped|what it|the stop handler)|^\[eval\] stopped' "$log" | cut -c1-160 | tr '\n' ' ')"
