#!/usr/bin/env bash
# On a GPU machine: time-to-policy for one legged task with the shipped defaults, with cold and warm kernel caches
# (each followed by test mode on 1024 envs), then throughput at 4096 and 8192 envs and the no-sync check.
# Usage: bash benchmarks/rounds/gpu_train_legged.sh TASK OUTDIR
set -uo pipefail
task=$1; out=$2
here=$(dirname "$0")
for cache in cold warm; do bash "$here/../gpu_policy.sh" "$task" "$cache" "$out/$cache"; done
for n in 4096 8192; do python3 "$here/../throughput.py" --task "$task" --num_envs $n 2>/dev/null | tail -1 | tee -a "$out/throughput.jsonl" | cut -c1-330; done
python3 "$here/../diagnostics/check_no_sync.py" --task "$task" --num_envs 4096 2>/dev/null | tail -1 | tee -a "$out/nosync.jsonl"
