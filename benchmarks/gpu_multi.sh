#!/usr/bin/env bash
# On a machine with >= 2 GPUs: a task's training throughput on 1 GPU and on K GPUs (torchrun, one simulator per GPU,
# distributed PPO), same envs per GPU, one row per K. Further arguments are Hydra overrides for every run, e.g.
# train.algorithm.class_name=PPO to measure rsl-rl-lib's own PPO update.
# Usage: [TASK=Anymal] bash benchmarks/gpu_multi.sh OUTDIR [K[,K...]] [ITERATIONS] [OVERRIDE ...]
set -uo pipefail
out=$1; ks=${2:-2}; its=${3:-40}; shift $(( $# < 3 ? $# : 3 )); mkdir -p "$out"
task=${TASK:-Anymal}
# NVLink multicast stays off on shared hosts.
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1
# A time limit per run: ranks that finish training but never exit (a hang while leaving the NCCL group) show as
# exit code 124 instead of holding the machine.
limit=${LIMIT_S:-300}
timeout $limit python3 train.py task=$task headless=True max_iterations=$its runs_dir="$out/$task.g1" "$@" \
  > "$out/$task.g1.log" 2>&1; rc=$?; [ $rc = 0 ] || tail -5 "$out/$task.g1.log"
codes="1:$rc"
for k in ${ks//,/ }; do
  timeout $limit torchrun --standalone --nnodes=1 --nproc_per_node=$k train.py task=$task multi_gpu=True \
    headless=True max_iterations=$its runs_dir="$out/$task.g$k" "$@" > "$out/$task.g$k.log" 2>&1; rc=$?
  [ $rc = 0 ] || tail -15 "$out/$task.g$k.log"
  codes="$codes,$k:$rc"
done
python3 - "$out" "$task" "$ks" "$*" "$codes" <<'PY'
import glob, json, statistics, sys
out, task, ks, overrides, codes = sys.argv[1:6]
def rate(k):
    s = json.load(open(sorted(glob.glob(f"{out}/{task}.g{k}/{task}/*/summary.json"))[-1]))
    h = s["history"][5:]  # skip the first iterations (kernel compilation, graph capture)
    steps = sum(x["env_steps"] - y["env_steps"] for x, y in zip(h[1:], h[:-1]))
    secs = sum(x["time_s"] - y["time_s"] for x, y in zip(h[1:], h[:-1]))
    split = {key: round(statistics.median(x[key] for x in h), 4) for key in ("collect_s", "learn_s")}
    return s["world_size"], steps / secs, split, s["num_envs"]
w1, r1, s1, n1 = rate(1)
for k in ks.split(","):
    wk, rk, sk, _ = rate(k)
    print(json.dumps({"task": task, "envs_per_gpu": n1, "overrides": overrides, "gpus": wk,
                      "train_env_steps_per_s": rk, "one_gpu_env_steps_per_s": r1, "speedup": rk / r1,
                      "efficiency": rk / r1 / wk, "median_split": sk, "median_split_1gpu": s1,
                      "exit_codes": codes}))
PY
