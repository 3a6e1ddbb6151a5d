#!/usr/bin/env bash
# Train jobs side by side, one per GPU, each for a fixed training time, then evaluate its best and last checkpoints
# in test mode on 1024 envs. Each job gets its own compile caches, the CUDA driver's included (ISAACGYMENVS_MW_CACHE:
# a cold start, as on a new node).
#
#   benchmarks/gpu_train_eval.sh OUT_DIR TRAIN_SECONDS "NAME GPU TASK SEED [train.py overrides...]" ...
#
# Writes OUT_DIR/<NAME>.train.log, <NAME>.eval_best.log, <NAME>.eval_last.log, <NAME>.summary.json and
# <NAME>.eval_{best,last}.json; OUT_DIR/<NAME>.done when the job has finished. The overrides go to training and
# evaluation alike (learner=rl_games, train.* keys). DRY_RUN_OVERRIDES are added after every job's own, to try the
# jobs on the CPU before spending GPU time on them:
#   DRY_RUN_OVERRIDES="sim_device=cpu rl_device=cpu num_envs=8 max_iterations=2" \
#     bash benchmarks/gpu_train_eval.sh OUT 60 "NAME 0 TASK SEED [overrides...]" ...
# (a dry run also keeps the machine's compile caches).
# COPY_BEST=1 also copies each job's best checkpoint to OUT_DIR/<NAME>.model_best.pt, to study the policy or record a
# clip of it elsewhere (test mode on the CPU takes it as checkpoint=...).
set -u
out=$1; seconds=$2; shift 2
mkdir -p "$out"
for spec in "$@"; do
  read -r name gpu task seed extra <<<"$spec"
  extra="$extra ${DRY_RUN_OVERRIDES:-}"
  (
    export CUDA_VISIBLE_DEVICES=$gpu PYTHONUNBUFFERED=1
    if [ -z "${DRY_RUN_OVERRIDES:-}" ]; then  # a dry run keeps the machine's caches: it checks the round, not its speed
      unset WARP_CACHE_PATH TORCHINDUCTOR_CACHE_DIR TRITON_CACHE_DIR CUDA_CACHE_PATH
      export ISAACGYMENVS_MW_CACHE=/tmp/cache/$name
    fi
    runs=/tmp/runs/$name
    # shellcheck disable=SC2086  # the overrides are words
    python train.py task="$task" seed="$seed" headless=True runs_dir="$runs" max_train_time_s="$seconds" \
      $extra >"$out/$name.train.log" 2>&1
    run_dir=$(dirname "$(ls -t "$runs"/*/*/summary.json | head -1)")
    cp "$run_dir/summary.json" "$out/$name.summary.json"
    last=$run_dir/$(ls "$run_dir" | grep -E '^model_[0-9]+(_interrupted)?\.pt$' | sort -t_ -k2 -n | tail -1)
    for which in best last; do
      ckpt=$run_dir/model_best.pt; [ "$which" = last ] && ckpt=$last
      # shellcheck disable=SC2086
      python train.py task="$task" seed=11 headless=True test=True num_envs=1024 checkpoint="$ckpt" $extra \
        >"$out/$name.eval_$which.log" 2>&1
      eval_json=$(ls -t "$run_dir"/eval*.json | head -1)
      cp "$eval_json" "$out/$name.eval_$which.json"
    done
    if [ "${COPY_BEST:-0}" = 1 ] && [ -f "$run_dir/model_best.pt" ]; then cp "$run_dir/model_best.pt" "$out/$name.model_best.pt"; fi
    touch "$out/$name.done"
  ) &
done
wait
