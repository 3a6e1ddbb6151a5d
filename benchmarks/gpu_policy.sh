#!/usr/bin/env bash
# On a GPU machine: time to a walking policy for one task with the shipped defaults, then test mode on 1024 envs.
# CACHE=cold first empties Warp's kernel cache and the compiled step's Inductor/Triton caches.
# Usage: bash benchmarks/gpu_policy.sh TASK cold|warm OUTDIR [LIMIT_S]  (training limit, default 400 s; the whole
# test-mode line goes to OUTDIR/TASK.CACHE.eval.txt)
set -uo pipefail
task=$1; cache=$2; out=$3; limit=${4:-400}
mkdir -p "$out"
[ "$cache" = cold ] && rm -rf "${HOME}/.cache/warp" "/tmp/torchinductor_$(whoami)" "${HOME}/.triton/cache"
t0=$(date +%s.%N)
# --preserve-status: the run's own exit status (143: stopped by the SIGTERM as designed; 139: a segfault), not 124
timeout --preserve-status "$limit" python3 train.py task="$task" headless=True runs_dir="$out/runs" > "$out/$task.$cache.log" 2>&1
rc=$?
t1=$(date +%s.%N)
grep -E "^\[it +(1|2|100|200|300|400|500)/|compiled|\[train\] done|Error" "$out/$task.$cache.log" | cut -c1-140
python3 -c "print('$task $cache: train.py rc=$rc, process wall %.1f s' % ($t1 - $t0))"
ckpt=$(ls -t "$out"/runs/"$task"/*/model_[0-9]*.pt 2>/dev/null | head -1)
[ -n "$ckpt" ] || exit 1
timeout 120 python3 train.py task="$task" headless=True test=True checkpoint="$ckpt" num_envs=1024 2>&1 | grep "\[eval\] {" | tee "$out/$task.$cache.eval.txt" | cut -c1-260
cp "$(dirname "$ckpt")/summary.json" "$out/$task.$cache.summary.json"
