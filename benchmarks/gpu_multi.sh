#!/usr/bin/env bash
# On a machine with >= 2 GPUs: Anymal training throughput on 1 GPU and on K GPUs (torchrun, one simulator per
# GPU, distributed PPO), same envs per GPU. Further arguments are Hydra overrides for both runs, e.g.
# train.algorithm.class_name=PPO to measure rsl-rl-lib's own PPO update.
# Usage: bash benchmarks/gpu_multi.sh OUTDIR [K] [ITERATIONS] [OVERRIDE ...]
set -uo pipefail
out=$1; k=${2:-2}; its=${3:-40}; shift $(( $# < 3 ? $# : 3 )); mkdir -p "$out"
# NVLink multicast stays off on shared hosts.
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1
# A time limit per run: ranks that finish training but never exit (a hang while leaving the NCCL group) show as
# exit code 124 instead of holding the machine.
limit=${LIMIT_S:-300}
timeout $limit python3 train.py task=Anymal headless=True max_iterations=$its runs_dir="$out/g1" "$@" \
  > "$out/g1.log" 2>&1; rc1=$?; [ $rc1 = 0 ] || tail -5 "$out/g1.log"
timeout $limit torchrun --standalone --nnodes=1 --nproc_per_node=$k train.py task=Anymal multi_gpu=True headless=True \
  max_iterations=$its runs_dir="$out/g$k" "$@" > "$out/g$k.log" 2>&1; rck=$?; [ $rck = 0 ] || tail -15 "$out/g$k.log"
python3 - "$out" "$k" "$*" "$rc1" "$rck" <<'PY'
import glob, json, statistics, sys
out, k, overrides, rc1, rck = sys.argv[1:6]
def rate(d):
    s = json.load(open(sorted(glob.glob(f"{out}/{d}/Anymal/*/summary.json"))[-1]))
    h = s["history"][5:]  # skip the first iterations (kernel compilation, graph capture)
    steps = sum(x["env_steps"] - y["env_steps"] for x, y in zip(h[1:], h[:-1]))
    secs = sum(x["time_s"] - y["time_s"] for x, y in zip(h[1:], h[:-1]))
    split = {key: round(statistics.median(x[key] for x in h), 4) for key in ("collect_s", "learn_s")}
    return s["world_size"], steps / secs, split
w1, r1, s1 = rate("g1"); wk, rk, sk = rate(f"g{k}")
print(json.dumps({"task": "Anymal", "envs_per_gpu": 4096, "overrides": overrides, "gpus_1": w1,
                  "train_env_steps_per_s_1gpu": r1, "median_split_1gpu": s1, f"gpus_{k}": wk,
                  f"train_env_steps_per_s_{k}gpu": rk, f"median_split_{k}gpu": sk, "speedup": rk / r1,
                  "exit_codes": {"1gpu": int(rc1), f"{k}gpu": int(rck)}}))
PY
