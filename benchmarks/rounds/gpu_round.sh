#!/usr/bin/env bash
# One GPU session: captured-step check, Cartpole and Go1 time-to-policy (warm cache after the check compiles),
# the throughput table, no-sync checks. Usage: bash benchmarks/rounds/gpu_round.sh OUTDIR
set -uo pipefail
out=$1; mkdir -p "$out"
here=$(dirname "$0")
timeout 150 python3 "$here/../diagnostics/check_step_graph.py" --task Go1 2>"$out/check.err" | tail -1 || tail -5 "$out/check.err"
for task in Cartpole Go1; do bash "$here/../gpu_policy.sh" "$task" warm "$out"; done
bash "$here/gpu_compile.sh" "$out"
for task in Go1 Anymal; do timeout 60 python3 "$here/../diagnostics/check_no_sync.py" --task $task --num_envs 4096 2>/dev/null | tail -1; done
