#!/usr/bin/env bash
# On a GPU machine: train a legged task with the shipped defaults, then evaluate the final policy on 1024 envs.
# Usage: bash benchmarks/gpu_train_legged.sh TASK OUTDIR [extra train.py overrides...]
set -uo pipefail
task=$1; out=$2; shift 2
mkdir -p "$out"
start=$(date +%s.%N)
python3 train.py task="$task" headless=True runs_dir="$out/runs" "$@" > "$out/$task.train.log" 2>&1
rc=$?
end=$(date +%s.%N)
grep -E "^\[it +([0-9]*[05]0|1)/|\[train\]|Error|error" "$out/$task.train.log" | grep -v "^Module" | tail -20
echo "$task train rc=$rc wall=$(echo "$end - $start" | bc) s"
ckpt=$(ls -t "$out"/runs/"$task"/*/model_*.pt 2>/dev/null | head -1)
[ -n "$ckpt" ] || exit 1
python3 train.py task="$task" headless=True test=True checkpoint="$ckpt" num_envs=1024 "$@" 2>&1 | grep "\[eval\] {"
cp "$(dirname "$ckpt")/summary.json" "$out/$task.summary.json"
cp "$ckpt" "$out/$task.model.pt"
