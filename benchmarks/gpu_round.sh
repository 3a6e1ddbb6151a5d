#!/usr/bin/env bash
# One GPU session: captured-step check, Go1 and Cartpole time-to-policy (warm cache after the check compiles),
# throughput table, no-sync checks. Usage: bash benchmarks/gpu_round.sh OUTDIR
set -uo pipefail
out=$1; mkdir -p "$out"
timeout 150 python3 benchmarks/check_step_graph.py --task Go1 2>"$out/check.err" | tail -1 || tail -5 "$out/check.err"
for task in Cartpole Go1; do
  t0=$(date +%s.%N)
  timeout 240 python3 train.py task=$task headless=True runs_dir="$out/runs" > "$out/$task.log" 2>&1
  t1=$(date +%s.%N)
  grep -E "\[train\] done|Error" "$out/$task.log" | cut -c1-150
  python3 -c "print('$task warm: process wall %.1f s' % ($t1 - $t0))"
  ckpt=$(ls -t "$out"/runs/$task/*/model_*.pt 2>/dev/null | head -1)
  [ -n "$ckpt" ] && timeout 60 python3 train.py task=$task headless=True test=True checkpoint="$ckpt" num_envs=1024 2>&1 | grep "\[eval\] {" | cut -c1-230
  cp "$(dirname "$ckpt")/summary.json" "$out/$task.summary.json" 2>/dev/null
done
for t in "Cartpole 4096" "Cartpole 16384" "Cartpole 65536" "Go1 4096" "Go1 8192" "Anymal 4096" "Anymal 8192"; do
  set -- $t
  timeout 90 python3 benchmarks/throughput.py --task $1 --num_envs $2 2>/dev/null | tail -1 | tee -a "$out/throughput.jsonl" | cut -c1-300
done
for task in Go1 Anymal; do timeout 60 python3 benchmarks/check_no_sync.py --task $task --num_envs 4096 2>/dev/null | tail -1; done
