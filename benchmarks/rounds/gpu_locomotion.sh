#!/usr/bin/env bash
# On a GPU machine: Ant and Humanoid with the shipped defaults (issue 12's acceptance runs).
#   1. a short warm-up run per task fills Warp's kernel cache and the compiled step's caches (not measured);
#   2. a warm training run per task with the shipped defaults: train.py's summary.json gives wall_time_s (process
#      start to end, start-up included) and the history for the learning curve;
#   3. test mode on 1024 envs (eval.json: forward_speed in m/s, timeout_fraction, mean episode length);
#   4. the learning curve PNG per task, and throughput rows (a), (b), (c) at 4096 and 8192 envs.
# Usage: [TASKS="Ant"] bash benchmarks/rounds/gpu_locomotion.sh OUTDIR [extra train.py overrides for both tasks...]
# (TASKS picks the tasks, default "Ant Humanoid"; one task per call fits the device tool's 600-s calls)
set -uo pipefail
out=$1; shift
here=$(dirname "$0")
mkdir -p "$out"
for task in ${TASKS:-Ant Humanoid}; do
  timeout 300 python3 train.py task=$task headless=True max_iterations=3 runs_dir="$out/warmup" "$@" \
    > "$out/$task.warmup.log" 2>&1
  limit=$([ $task = Ant ] && echo 300 || echo 600)
  timeout $limit python3 train.py task=$task headless=True runs_dir="$out/runs" "$@" > "$out/$task.log" 2>&1
  echo "$task train.py rc=$?"
  grep -E "^\[it +(1|50|100|200|300|400|500|600|700|800|900|1000)/|compiled|\[train\] done|Error" "$out/$task.log" \
    | cut -c1-150
  run=$(ls -td "$out"/runs/$task/*/ 2>/dev/null | head -1)
  ckpt=$(ls -t "$run"model_[0-9]*.pt 2>/dev/null | head -1)
  [ -n "$ckpt" ] || continue
  python3 -c "import json; s = json.load(open('${run}summary.json')); print('$task', {k: s[k] for k in
    ('wall_time_s', 'train_time_s', 'env_steps', 'env_steps_per_s', 'mean_episode_reward', 'mean_episode_length')})"
  timeout 300 python3 train.py task=$task headless=True test=True checkpoint="$ckpt" num_envs=1024 "$@" 2>&1 \
    | grep "\[eval\] {" | cut -c1-300
  cp "${run}summary.json" "$out/$task.summary.json"
  cp "$(dirname "$ckpt")/eval.json" "$out/$task.eval.json" 2>/dev/null
  python3 "$here/../learning_curve.py" "${run}summary.json" --length --out "$out/${task,,}_learning_curve.png"
  for n in 4096 8192; do
    python3 "$here/../throughput.py" --task $task --num_envs $n 2>/dev/null | tail -1 \
      | tee -a "$out/throughput.jsonl" | cut -c1-330
  done
done
for task in ${TASKS:-Ant Humanoid}; do
  python3 "$here/../diagnostics/check_no_sync.py" --task $task --num_envs 4096 2>/dev/null | tail -1 | tee -a "$out/nosync.jsonl"
done
# compiled+captured step vs eager step; Ant (no falls, hence no randomly drawn resets, within 60 small-action steps)
[[ " ${TASKS:-Ant} " == *" Ant "* ]] && python3 "$here/../diagnostics/check_step_graph.py" --task Ant --num_envs 1024 --steps 60 2>/dev/null | tail -1 \
  | tee -a "$out/step_graph.jsonl"
