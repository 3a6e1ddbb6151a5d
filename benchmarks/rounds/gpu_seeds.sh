#!/usr/bin/env bash
# On a GPU machine: train several runs of one task side by side on one GPU, then evaluate each on 1024 envs.
# For robustness across seeds and for screening settings; wall clocks of side-by-side runs are not times to a
# policy (the runs share the GPU): take those from gpu_policy.sh.
# Usage: bash benchmarks/rounds/gpu_seeds.sh TASK OUTDIR "seed=1" "seed=2 task.env.x=y" ...   (one run per argument)
# TRAIN_LIMIT_S (default 560) caps each training run. OUTDIR/done appears when everything is written, so a batch
# longer than one device call can run detached and be waited for in the next call:
#   call 1: TRAIN_LIMIT_S=900 setsid nohup bash benchmarks/rounds/gpu_seeds.sh Anymal /tmp/s "seed=1" ... > /tmp/s.log 2>&1 &
#   call 2: while [ ! -f /tmp/s/done ]; do sleep 10; done; cat /tmp/s/evals.txt
set -uo pipefail
task=$1; out=$2; shift 2
mkdir -p "$out"; rm -f "$out/done"
i=0
for args in "$@"; do
  i=$((i + 1))
  # shellcheck disable=SC2086
  (timeout "${TRAIN_LIMIT_S:-560}" python3 train.py task="$task" headless=True runs_dir="$out/runs$i" $args > "$out/train$i.log" 2>&1;
   echo "rc=$?" >> "$out/train$i.log") &
done
wait
# The evaluations run side by side too; their results are printed in run order.
i=0
for args in "$@"; do
  i=$((i + 1))
  ckpt=$(ls -t "$out"/runs$i/*/*/model_[0-9]*.pt 2>/dev/null | head -1)
  if [ -z "$ckpt" ]; then echo "no checkpoint" > "$out/eval$i.txt"; tail -3 "$out/train$i.log" >> "$out/eval$i.txt"; continue; fi
  cp "$(dirname "$ckpt")/summary.json" "$out/summary$i.json"
  # shellcheck disable=SC2086
  (timeout 200 python3 train.py task="$task" headless=True test=True checkpoint="$ckpt" num_envs=1024 $args \
     2>&1 | grep "\[eval\] {" > "$out/eval$i.txt") &
done
wait
i=0
for args in "$@"; do
  i=$((i + 1))
  echo "run $i ($args): $(grep -o 'done in [0-9.]*s' "$out/train$i.log") $(cut -c8-400 "$out/eval$i.txt")" \
    | tee -a "$out/evals.txt"
done
touch "$out/done"
