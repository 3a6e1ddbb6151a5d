#!/usr/bin/env bash
# On a GPU machine: time-to-policy for one legged task with the shipped defaults, with cold and warm kernel caches
# (Warp's, and the compiled step's Inductor/Triton caches), each followed by test mode on 1024 envs; then throughput at 4096 and 8192 envs and the no-sync check.
# Usage: bash benchmarks/gpu_train_legged.sh TASK OUTDIR
set -uo pipefail
task=$1; out=$2
mkdir -p "$out"
for cache in cold warm; do
  [ "$cache" = cold ] && rm -rf "${HOME}/.cache/warp" "/tmp/torchinductor_$(whoami)" "${HOME}/.triton/cache"
  t0=$(date +%s.%N)
  python3 train.py task="$task" headless=True runs_dir="$out/runs_$cache" > "$out/$task.$cache.log" 2>&1
  rc=$?
  t1=$(date +%s.%N)
  grep -E "^\[it +(1|100|200|300|400|500)/|\[train\] done|Error" "$out/$task.$cache.log" | cut -c1-120
  python3 -c "print('$task $cache: train.py rc=$rc, process wall %.1f s' % ($t1 - $t0))"
  ckpt=$(ls -t "$out"/runs_$cache/"$task"/*/model_*.pt 2>/dev/null | head -1)
  [ -n "$ckpt" ] || continue
  python3 train.py task="$task" headless=True test=True checkpoint="$ckpt" num_envs=1024 2>&1 | grep "\[eval\] {" | cut -c1-260
  cp "$(dirname "$ckpt")/summary.json" "$out/$task.$cache.summary.json"
done
for n in 4096 8192; do python3 benchmarks/throughput.py --task "$task" --num_envs $n 2>/dev/null | tail -1 | tee -a "$out/throughput.jsonl" | cut -c1-330; done
python3 benchmarks/check_no_sync.py --task "$task" --num_envs 4096 2>/dev/null | tail -1 | tee -a "$out/nosync.jsonl"
